"""The package's shape: imports run one way through the layers, and privacy is a package boundary.

Layers, lowest first (a module may import from its own layer and the layers below it only)::

    floor       geometry, camera, frame, config, validation, viz   (maths, intrinsics, frames, settings)
    runtime     compile cache, exported programs, machine record    (internal)
    estimator   two frames in, one MotionEstimate out
    tracking    frames in, poses out
    data        recordings, trajectories and outputs on disk
    synthetic   generated scenes and augmentations of recordings
    evaluation  metrics, evaluation against ground truth, peers
    pipelines   what each command does, as library calls
    cli         the command line

Read from the source with :mod:`ast` (every ``import`` and ``from ... import``, also inside
functions), so a lazy import cannot hide an upward dependency.
"""
from __future__ import annotations

import ast
from pathlib import Path

import pytest

PACKAGE = Path(__file__).resolve().parents[2] / "jaxvo"
LAYERS = ["floor", "runtime", "estimator", "tracking", "data", "synthetic", "evaluation", "pipelines", "cli"]
FLOOR = {"geometry", "camera", "frame", "config", "validation", "viz"}


def _unit(module: str) -> str:
    """The package (second dotted part) of a ``jaxvo.*`` module, or "" for ``jaxvo`` itself."""
    parts = module.split(".")
    return parts[1] if len(parts) > 1 else ""


def _layer(unit: str) -> str:
    if unit == "__main__":      # ``python -m jaxvo``: the command line
        return "cli"
    return "floor" if unit in FLOOR or unit == "" else unit


def _modules():
    for path in sorted(PACKAGE.rglob("*.py")):
        rel = path.relative_to(PACKAGE.parent).with_suffix("")
        parts = list(rel.parts)
        if parts[-1] == "__init__":
            parts = parts[:-1]
        yield ".".join(parts), path


def _imports(module: str, path: Path):
    """(imported module, imported name or None, line) for every import of a jaxvo module."""
    tree = ast.parse(path.read_text(), str(path))
    package = module if path.name == "__init__.py" else module.rsplit(".", 1)[0]
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            for a in node.names:
                if a.name.startswith("jaxvo"):
                    yield a.name, None, node.lineno
        elif isinstance(node, ast.ImportFrom):
            base = node.module or ""
            if node.level:
                base = ".".join(package.split(".")[: len(package.split(".")) - node.level + 1] + ([base] if base else []))
            if base.startswith("jaxvo"):
                for a in node.names:
                    sub = f"{base}.{a.name}"
                    is_module = (PACKAGE.parent / sub.replace(".", "/")).with_suffix(".py").exists() or \
                        (PACKAGE.parent / sub.replace(".", "/")).is_dir()
                    yield (sub, None, node.lineno) if is_module else (base, a.name, node.lineno)


MODULES = dict(_modules())


def test_every_module_belongs_to_a_layer():
    units = {_unit(m) for m in MODULES}
    unknown = sorted(u for u in units if _layer(u) not in LAYERS)
    assert not unknown, f"modules outside the layers {LAYERS}: {unknown} (add them to a layer in this test's docstring)"


@pytest.mark.parametrize("module", sorted(m for m in MODULES if _unit(m)))
def test_imports_only_go_down(module):
    own = LAYERS.index(_layer(_unit(module)))
    upward = []
    for target, _, line in _imports(module, MODULES[module]):
        unit = _unit(target)
        if unit == "":          # the top-level jaxvo package re-exports everything: never from inside
            upward.append(f"line {line}: imports the top-level jaxvo package")
        elif LAYERS.index(_layer(unit)) > own:
            upward.append(f"line {line}: {target} ({_layer(unit)} is above {_layer(_unit(module))})")
    assert not upward, f"{module} imports upward:\n" + "\n".join(upward)


@pytest.mark.parametrize("module", sorted(MODULES))
def test_no_private_name_crosses_a_package(module):
    here = _layer(_unit(module))     # the floor modules are one package: jaxvo's own top level
    crossing = []
    for target, name, line in _imports(module, MODULES[module]):
        if _layer(_unit(target)) == here:
            continue
        private_parts = [p for p in target.split(".")[1:] if p.startswith("_") and p != "__init__"]
        if private_parts or (name and name.startswith("_")):
            crossing.append(f"line {line}: {target}{'.' + name if name else ''}")
    assert not crossing, f"{module} imports private names of another package:\n" + "\n".join(crossing)


def test_the_estimator_imports_nothing_above_it():
    above = {"tracking", "data", "synthetic", "evaluation", "pipelines", "cli"}
    bad = [(m, t) for m in MODULES if _unit(m) == "estimator"
           for t, _, _ in _imports(m, MODULES[m]) if _unit(t) in above]
    assert not bad, bad

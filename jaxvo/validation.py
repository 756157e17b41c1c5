"""Table-driven checks of plain-data settings (:class:`jaxvo.Config`, :class:`jaxvo.TrackConfig`,
:class:`jaxvo.Camera`).

Each settings class keeps a table ``{field name: Rule}`` next to its definition, and
:func:`check_fields` checks every field of an instance against it: the type (integers where a
static integer is required, numbers that are neither bool, None nor str), finiteness and the
allowed range. The first violation raises a ``ValueError`` naming the field, the value and what
is allowed, e.g. ``Config.p must be a number in (0, 1), got 1.5``. A field without a rule is an
error too, so a new field cannot slip through unchecked.

Numeric values may be Python numbers, NumPy scalars or concrete arrays (a ``jax.vmap`` sweep
over a field: every element is checked); traced values inside a user's ``jit`` / ``vmap`` are
not concrete and are skipped.
"""
from __future__ import annotations

import dataclasses
import difflib
import numbers
from typing import Any, Dict, Mapping, Optional, Tuple, Union

import numpy as np

__all__ = ["Rule", "real", "number", "integer", "choice", "positive_ints", "flag", "check_fields", "check_values",
           "check_names"]

Bound = Union[None, float, str]   # a number, or the name of another field of the same object


@dataclasses.dataclass(frozen=True)
class Rule:
    """What one field may hold.

    kind: "real" (a number, a NumPy/JAX array of numbers, or a tracer), "int" (a Python or
      NumPy integer: it fixes shapes or control flow), "choice" (one of ``choices``),
      "ints" (a tuple of integers, each within the bounds) or "bool".
    lo, hi: bounds (None = unbounded), either numbers or the name of another field whose value
      is the bound (e.g. ``lag < max_gap``); ``lo_open`` / ``hi_open`` exclude the bound itself.
    none: None is allowed too (``none_means`` says what it means, for the message).
    scalar: "real" only: a single number (no array: a function argument, not a swept field).
    """
    kind: str
    lo: Bound = None
    hi: Bound = None
    lo_open: bool = False
    hi_open: bool = False
    choices: Tuple[Any, ...] = ()
    none: bool = False
    none_means: str = ""
    scalar: bool = False


def real(lo: Bound = None, hi: Bound = None, lo_open: bool = False, hi_open: bool = False,
         none_means: str = "") -> Rule:
    """A number or an array of numbers, None too when ``none_means`` says what it means."""
    return Rule("real", lo, hi, lo_open, hi_open, none=bool(none_means), none_means=none_means)


def number(lo: Bound = None, hi: Bound = None, lo_open: bool = False, none_means: str = "") -> Rule:
    """A single number (an argument; ``real`` also takes arrays), None too when ``none_means`` says what it means."""
    return Rule("real", lo, hi, lo_open, none=bool(none_means), none_means=none_means, scalar=True)


def integer(lo: Bound = None, hi: Bound = None, hi_open: bool = False, none_means: str = "") -> Rule:
    return Rule("int", lo, hi, False, hi_open, none=bool(none_means), none_means=none_means)


def choice(*values) -> Rule:
    return Rule("choice", choices=tuple(values))


def positive_ints(none_means: str = "") -> Rule:
    return Rule("ints", lo=1, none=bool(none_means), none_means=none_means)


def flag() -> Rule:
    return Rule("bool")


def _fmt_bound(b) -> str:
    return f"{b:g}" if isinstance(b, float) else str(b)


def _allowed(rule: Rule, lo, hi) -> str:
    """Human-readable allowed set, e.g. 'a number in (0, 1)' or 'an integer >= 1'."""
    if rule.kind == "choice":
        return "one of " + ", ".join(map(repr, rule.choices))
    if rule.kind == "bool":
        return "True or False" + (f", or None ({rule.none_means})" if rule.none else "")
    noun = {"real": "a number", "int": "an integer", "ints": "a tuple of integers"}[rule.kind]
    if rule.kind == "ints":
        noun += ", each"
    if lo is not None and hi is not None:
        rng = f"in {'(' if rule.lo_open else '['}{_fmt_bound(lo)}, {_fmt_bound(hi)}{')' if rule.hi_open else ']'}"
    elif lo is not None:
        rng = f"{'>' if rule.lo_open else '>='} {_fmt_bound(lo)}"
    elif hi is not None:
        rng = f"{'<' if rule.hi_open else '<='} {_fmt_bound(hi)}"
    else:
        rng = "finite"
    s = f"{noun} {rng}"
    if rule.none:
        s += f", or None ({rule.none_means})"
    return s


def _is_tracer(x) -> bool:
    try:
        import jax
    except ImportError:  # pragma: no cover
        return False
    return isinstance(x, jax.core.Tracer)


def _numbers(x) -> Optional[np.ndarray]:
    """x as a float64 array if it is numeric (not bool / str / None / object), else None."""
    if isinstance(x, (bool, np.bool_, str, bytes)) or x is None:
        return None
    if isinstance(x, numbers.Number):
        return np.asarray(x, np.float64) if isinstance(x, numbers.Real) else None
    try:
        a = np.asarray(x)
    except Exception:
        return None
    if a.dtype == bool or not (np.issubdtype(a.dtype, np.integer) or np.issubdtype(a.dtype, np.floating)):
        return None
    return a.astype(np.float64)


def _is_int(x) -> bool:
    return isinstance(x, (int, np.integer)) and not isinstance(x, (bool, np.bool_))


def _in_range(a: np.ndarray, rule: Rule, lo, hi) -> bool:
    ok = np.isfinite(a)
    if lo is not None:
        ok &= (a > lo) if rule.lo_open else (a >= lo)
    if hi is not None:
        ok &= (a < hi) if rule.hi_open else (a <= hi)
    return bool(np.all(ok))


def _show(x) -> str:
    if isinstance(x, np.ndarray) and x.ndim > 0:
        return f"array of shape {x.shape}" if x.size > 4 else repr(x.tolist())
    r = repr(x)
    return r if len(r) <= 60 else r[:57] + "..."


def _bound(b: Bound, values: Mapping[str, Any]):
    """A bound as a number: itself, or the value of the field it names (None while that field is
    None or not an integer: its own rule reports it)."""
    if isinstance(b, str):
        v = values[b]
        return float(v) if _is_int(v) else None
    return b


def check_fields(obj, rules: Mapping[str, Rule], what: str) -> None:
    """Check every field of ``obj`` (a dataclass or NamedTuple) against ``rules``.

    ``what`` prefixes the field names in messages (``"config"`` -> ``config.p``). Raises
    ValueError on the first field that breaks its rule, and on a field without a rule.
    """
    names = [f.name for f in dataclasses.fields(obj)] if dataclasses.is_dataclass(obj) else list(obj._fields)
    missing = [n for n in names if n not in rules]
    if missing:
        raise ValueError(f"{what}: field(s) {', '.join(missing)} have no validation rule "
                         f"(add them to the table next to {type(obj).__name__})")
    _check({n: getattr(obj, n) for n in names}, rules, f"{what}.")


def check_values(values: Mapping[str, Any], rules: Mapping[str, Rule], what: str) -> None:
    """Check a function's arguments ``values`` ({name: value}) against ``rules`` (one each), as
    :func:`check_fields` checks fields; messages read ``"{what}: name must be ..."``, e.g.
    ``open_sequence: max_frames must be an integer >= 1, or None (all frames), got '10'``."""
    _check(dict(values), rules, f"{what}: ")


def _check(values: Dict[str, Any], rules: Mapping[str, Rule], prefix: str) -> None:
    """Raise ValueError on the first of ``values`` that breaks its rule (``prefix`` + name in the message)."""
    for name in values:
        rule, x = rules[name], values[name]

        lo, hi = _bound(rule.lo, values), _bound(rule.hi, values)

        def fail():
            refs = [f"{b} = {values[b]}" for b in (rule.lo, rule.hi) if isinstance(b, str) and values[b] is not None]
            extra = f" ({', '.join(refs)})" if refs else ""
            raise ValueError(f"{prefix}{name} must be {_allowed(rule, lo, hi)}{extra}, got {_show(x)}")

        if x is None:
            if not rule.none:
                fail()
            continue
        if rule.kind == "choice":
            if not any(type(x) is type(c) and x == c for c in rule.choices):
                fail()
        elif rule.kind == "bool":
            if not isinstance(x, (bool, np.bool_)):
                fail()
        elif rule.kind == "int":
            if not _is_int(x) or not _in_range(np.asarray(float(x)), rule, lo, hi):
                fail()
        elif rule.kind == "ints":
            if not isinstance(x, tuple) or not all(_is_int(b) for b in x) \
                    or not all(_in_range(np.asarray(float(b)), rule, lo, hi) for b in x):
                fail()
        else:
            if _is_tracer(x):
                continue
            a = _numbers(x)
            if a is None or (rule.scalar and a.ndim != 0) or not _in_range(a, rule, lo, hi):
                fail()


def check_names(given, known, what: str) -> None:
    """Raise ValueError naming the names in ``given`` that are not in ``known`` (with close matches)."""
    unknown = [n for n in given if n not in known]
    if unknown:
        hints = []
        for n in unknown:
            close = difflib.get_close_matches(str(n), list(known), n=1)
            hints.append(f"{n!r}" + (f" (did you mean {close[0]!r}?)" if close else ""))
        raise ValueError(f"unknown {what} field(s) {', '.join(hints)}; known: {', '.join(sorted(known))}")

"""What each command does, callable from Python: run sequences, maps, hindsight masks, the demo."""

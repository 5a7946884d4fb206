"""Taking samples: the session state machine, the capture rule, the runner, live fit and progress."""

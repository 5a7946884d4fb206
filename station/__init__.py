"""The station: configuration, sessions, command line, live view."""

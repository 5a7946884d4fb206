"""The station's files: robot and setup tables, samples, plans, session folders, the IPA series."""

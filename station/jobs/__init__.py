"""The jobs behind the commands: calibration service and report, method comparison, plan design."""

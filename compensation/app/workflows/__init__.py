"""Workflows: the orchestration behind the commands, one module each (compare, demo, simulate,
compensate, calibration, identification, controller_tables, diagnosis, benchmark). A workflow
takes a settings object, returns a result and writes progress to stderr; it parses no arguments."""

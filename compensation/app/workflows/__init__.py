"""Workflows: the orchestration behind the commands (benchmark, diagnosis), one module each."""

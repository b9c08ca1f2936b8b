"""compensation: from an error field to corrected commands, evaluation, reports and the CLI.

May import ``errormap`` and ``training``.
"""

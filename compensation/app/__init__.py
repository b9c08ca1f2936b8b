"""The application wing: the ``volcomp`` command line, its commands, workflows and reports.

``cli.py`` and ``commands/`` (one module per sub-command: parse, call a workflow, print),
``options.py`` (option groups several commands share), ``workflows/`` (the orchestration),
``reports/`` (HTML reports and figures). May import ``errormap``, ``training`` and the library
part of ``compensation``; nothing outside ``compensation/app`` imports it (docs/explanation/architecture.md).
"""

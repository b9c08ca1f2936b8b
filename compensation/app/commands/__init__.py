"""One module per ``volcomp`` sub-command; each exposes ``register(subparsers)``.

A module's ``register`` adds its parser and sets ``func=run`` where
``run(args) -> int`` is the exit code.
"""

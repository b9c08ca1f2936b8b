"""errormap: physics and data for volcomp.

Transforms, machine models (the grinder's 23-error HTM model, the PKM models),
error elements, the truth simulator, feature points, identification and
diagnosis, and the I/O schemas. Imports neither ``training`` nor ``compensation``.
"""

__version__ = "0.1.0"

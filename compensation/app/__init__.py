"""The application wing of volcomp: the command line, its workflows and the HTML reports.

Nothing outside ``compensation.app`` imports it; it imports the library layers
(``errormap`` ← ``training`` ← ``compensation``) one way.
"""

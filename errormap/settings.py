"""Constructor settings kept as given: the one helper every estimator-like class stores its arguments with."""
from __future__ import annotations

import inspect


def settings_of(cls) -> list:
    """The names of ``cls``'s constructor arguments (``self`` and ``**kwargs`` left out)."""
    sig = inspect.signature(cls.__init__)
    return [p.name for p in sig.parameters.values() if p.name != "self" and p.kind != p.VAR_KEYWORD]


def keep_settings(obj, settings: dict) -> None:
    """Keep ``obj``'s constructor arguments as given, each as the attribute of its name (``settings``: the
    constructor's ``locals()``)."""
    for k in settings_of(type(obj)):
        setattr(obj, k, settings[k])

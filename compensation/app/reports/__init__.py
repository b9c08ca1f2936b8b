"""The HTML reports: one toolkit (:mod:`.toolkit`), one layout and one stylesheet (``templates/``)."""

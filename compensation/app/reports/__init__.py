"""Reports: what a person reads — the self-contained HTML reports and the figures."""

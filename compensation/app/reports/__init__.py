"""Reports: the self-contained HTML reports and their figures."""

"""Output: report.json / report.md, figures, the corrected tree."""

"""Reports: tables (CSV + Markdown with their settings) and plots (take a result and an ax)."""

"""Reports people read: Markdown/HTML, CSV and plots (matplotlib, Agg backend)."""

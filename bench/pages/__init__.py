"""The tables of the generated pages (``python -m bench.render_docs``): one function per
table, grouped by page."""

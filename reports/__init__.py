"""reports: what a person reads of a judged trace — self-contained HTML reports
(``reports.html``, for ``mcp-conform --html`` and ``mcp-capture check --html``) and
message-sequence charts as SVG (``reports.chart``). Rendering only: it judges nothing and
drives no node; it reads ``traceio`` and ``spec``."""

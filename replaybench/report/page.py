"""The frame of report.html and peak.html: their style sheet and the page around a body."""

from __future__ import annotations

__all__ = ['CSS', 'page_html']

CSS = """
:root{--fg:#1d1d1f;--muted:#666;--line:#ddd;--bg:#fff;--soft:#f6f7f9}
*{box-sizing:border-box}
body{margin:0;font:14px/1.45 system-ui,-apple-system,"Segoe UI",Roboto,sans-serif;
color:var(--fg);background:var(--bg)}
main{max-width:1180px;margin:0 auto;padding:20px 24px 48px}
h1{font-size:22px;margin:0 0 4px}
h2{font-size:18px;margin:28px 0 10px;padding-bottom:4px;border-bottom:1px solid var(--line)}
h3{font-size:15px;margin:18px 0 8px}
.meta{color:var(--muted);margin:0 0 12px}
.badge{display:inline-block;padding:1px 8px;border-radius:10px;font-weight:600;font-size:12px;
color:#fff;background:#777;vertical-align:2px}
.badge.complete{background:#2e7d32}.badge.interrupted{background:#e65100}
.badge.failed{background:#c62828}
.banner{border:1px solid #e0b000;background:#fff8e1;border-radius:6px;padding:10px 14px;
margin:12px 0}
.banner strong{display:block;margin-bottom:4px}
.banner ul{margin:4px 0 0;padding-left:20px}
.cards{display:grid;grid-template-columns:repeat(auto-fit,minmax(320px,1fr));gap:12px}
.card{background:var(--soft);border:1px solid var(--line);border-radius:6px;padding:10px 14px;
min-width:0;overflow-x:auto}
.card h3{margin:0 0 6px}
dl{display:grid;grid-template-columns:max-content 1fr;gap:2px 12px;margin:0}
dt{color:var(--muted)}dd{margin:0;overflow-wrap:anywhere}
table{border-collapse:collapse;width:100%;margin:6px 0 10px;font-variant-numeric:tabular-nums}
th,td{border-bottom:1px solid var(--line);padding:4px 8px;text-align:left;vertical-align:top}
th{background:var(--soft);font-weight:600;white-space:nowrap}
td.n,th.n{text-align:right;white-space:nowrap}
.swatch{display:inline-block;width:10px;height:10px;border-radius:2px;margin-right:6px}
.table-wrap{overflow-x:auto}
.charts{display:flex;flex-wrap:wrap;gap:10px}
svg.chart{max-width:100%;height:auto;background:#fff;border:1px solid var(--line);
border-radius:6px}
.samples{display:flex;flex-wrap:wrap;gap:12px}
figure{margin:0;max-width:482px}
figure img{max-width:100%;height:auto;border:1px solid var(--line);border-radius:4px}
figcaption{color:var(--muted);font-size:12px;overflow-wrap:anywhere}
code,pre{font:12px/1.4 ui-monospace,SFMono-Regular,Menlo,Consolas,monospace}
pre{background:var(--soft);border:1px solid var(--line);border-radius:6px;padding:10px;
overflow-x:auto;white-space:pre-wrap;overflow-wrap:anywhere}
details{margin:8px 0}summary{cursor:pointer;font-weight:600}
.muted{color:var(--muted)}
tr.peak td{font-weight:600;background:#eef7ee}
footer{margin-top:36px;color:var(--muted);font-size:12px}
@media print{svg.chart{border:none}details{display:block}}
"""


def page_html(title: str, body: str) -> str:
    """A whole self-contained page: ``title`` (HTML already) and ``body`` in its ``<main>``."""
    return (
        '<!DOCTYPE html>\n<html lang="en"><head><meta charset="utf-8">'
        '<meta name="viewport" content="width=device-width, initial-scale=1">'
        f'<title>{title}</title>'
        f'<style>{CSS}</style></head><body><main>{body}</main></body></html>\n'
    )

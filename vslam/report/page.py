"""The page of ``vslam report``: the inline style, the image-check script, escaping and formatting,
and matplotlib figures as embedded PNG ``data:`` URIs (no external URL at all)."""
from __future__ import annotations

import base64
import html
import io
from typing import Any

_CSS = """
body{font-family:system-ui,-apple-system,Segoe UI,Roboto,sans-serif;margin:24px auto;max-width:1100px;
color:#222;padding:0 16px}
h1{font-size:1.5em;margin-bottom:.2em}h2{font-size:1.2em;margin-top:1.6em;border-bottom:1px solid #ddd}
table{border-collapse:collapse;font-size:.9em;margin:.5em 0}td,th{border:1px solid #ddd;padding:3px 8px;
text-align:right}th{background:#f4f4f4}td:first-child,th:first-child{text-align:left}
.fig{display:inline-block;vertical-align:top;margin:6px 12px 6px 0}.fig img{max-width:100%;border:1px solid #eee}
.note{color:#666;font-size:.9em}.fail{color:#a50f15}code{background:#f4f4f4;padding:0 3px}
"""

_SCRIPT = """
(function(){
  var errors = [];
  window.addEventListener('error', function(e){ errors.push(String(e.message || e)); }, true);
  function check(){
    var imgs = document.images, ok = 0;
    for (var i = 0; i < imgs.length; i++) { if (imgs[i].complete && imgs[i].naturalWidth > 0) ok++; }
    var b = document.body;
    b.setAttribute('data-images-total', String(imgs.length));
    b.setAttribute('data-images-ok', String(ok));
    b.setAttribute('data-script-errors', String(errors.length));
    b.setAttribute('data-report-status', (ok === imgs.length && errors.length === 0) ? 'ready' : 'broken');
  }
  if (document.readyState === 'complete') check(); else window.addEventListener('load', check);
})();
"""


def esc(x: Any) -> str:
    return html.escape(str(x), quote=True)


def png_data_uri(fig) -> str:
    buf = io.BytesIO()
    fig.savefig(buf, format="png")
    return "data:image/png;base64," + base64.b64encode(buf.getvalue()).decode("ascii")


def img_tag(uri: str, alt: str) -> str:
    return f'<div class="fig"><img src="{uri}" alt="{esc(alt)}" title="{esc(alt)}"></div>'


def new_figure(w: float, h: float):
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    fig = Figure(figsize=(w, h), dpi=100)
    FigureCanvasAgg(fig)
    return fig


def fmt_value(v: Any) -> str:
    if v is None:
        return "-"
    if isinstance(v, bool):
        return "yes" if v else "no"
    if isinstance(v, float):
        return f"{v:.4g}" if abs(v) < 1e4 else f"{v:.0f}"
    return str(v)


def render_page(title: str, body: str) -> str:
    """A complete HTML document with the inline style and image-check script."""
    return (
        "<!DOCTYPE html>\n<html lang=\"en\"><head><meta charset=\"utf-8\">"
        f"<meta name=\"viewport\" content=\"width=device-width\"><title>{esc(title)}</title>"
        f"<style>{_CSS}</style></head>\n<body>\n{body}\n<script>{_SCRIPT}</script>\n</body></html>\n"
    )

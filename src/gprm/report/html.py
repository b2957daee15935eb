"""The self-contained HTML report: figures embedded as PNG data URIs, tables, provenance.

No network is needed to open it: no scripts, fonts or styles are fetched; the CSS is inline.
"""

from __future__ import annotations

import base64
import html
import io
import math
from dataclasses import dataclass, field


@dataclass
class Section:
    title: str
    anchor: str
    blocks: list = field(default_factory=list)   # HTML strings
    ran: bool = True


@dataclass(frozen=True)
class Card:
    label: str
    value: str
    note: str = ""
    tone: str = ""          # "", "ok", "warn", "bad"


def esc(x) -> str:
    return html.escape(str(x))


def fig_to_img(fig, caption: str, fig_id: str) -> str:
    """A matplotlib figure as an inline PNG inside <figure id=...> (the id is stable)."""
    import matplotlib.pyplot as plt

    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=120, bbox_inches="tight", facecolor="white")
    plt.close(fig)
    data = base64.b64encode(buf.getvalue()).decode("ascii")
    return (f'<figure id="{esc(fig_id)}"><img alt="{esc(caption)}" '
            f'src="data:image/png;base64,{data}"/><figcaption>{esc(caption)}</figcaption>'
            "</figure>")


def not_run(what: str, why: str) -> str:
    return f'<div class="notrun"><b>{esc(what)}: not run.</b> {esc(why)}</div>'


def table(headers, rows, caption: str = "", table_id: str = "", note: str = "") -> str:
    head = "".join(f"<th>{esc(h)}</th>" for h in headers)
    body = "".join("<tr>" + "".join(f"<td>{esc(c)}</td>" for c in r) + "</tr>" for r in rows)
    cap = f"<caption>{esc(caption)}</caption>" if caption else ""
    tid = f' id="{esc(table_id)}"' if table_id else ""
    foot = f'<p class="tnote">{esc(note)}</p>' if note else ""
    return (f'<div class="twrap"><table{tid}>{cap}<thead><tr>{head}</tr></thead>'
            f"<tbody>{body}</tbody></table>{foot}</div>")


def paragraph(text: str) -> str:
    return f"<p>{esc(text)}</p>"


_SUP = str.maketrans("-0123456789", "⁻⁰¹²³⁴⁵⁶⁷⁸⁹")


def _exp10(e: int) -> str:
    return f"× 10{str(e).translate(_SUP)}"


def num(value, digits: int = 4) -> str:
    """A number with ``digits`` significant digits; powers of ten as × 10ⁿ."""
    if value is None or not math.isfinite(value):
        return "—"
    if value == 0:
        return "0"
    e = int(math.floor(math.log10(abs(value))))
    if -3 <= e < 5:
        return f"{value:.{digits}g}"
    return f"{value / 10 ** e:.{digits - 1}f} {_exp10(e)}"


def pm(value, err, scale: float = 1.0) -> str:
    """``value ± err`` rounded to the error's two significant digits (``(a ± b) × 10ⁿ`` for
    very large or small values)."""
    if value is None or not math.isfinite(value):
        return "—"
    v = value * scale
    if err is None or not math.isfinite(err) or err <= 0:
        return num(v)
    e = err * scale
    if e >= abs(v):
        # the error exceeds the value (not determined, or a parameter at zero): rounding the
        # value to the error's digits would print it as 0; give both their own digits
        return f"{num(v, 3)} ± {num(e, 2)}"
    big = max(abs(v), e)
    p = int(math.floor(math.log10(big))) if big > 0 else 0
    shift = p if (p >= 5 or p < -3) else 0
    v, e = v / 10 ** shift, e / 10 ** shift
    digits = max(0, 1 - int(math.floor(math.log10(e))))
    txt = f"{v:.{digits}f} ± {e:.{digits}f}" if digits <= 10 else f"{v:.3g} ± {e:.2g}"
    return f"({txt}) {_exp10(shift)}" if shift else txt


CSS = """
:root{--accent:#c2410c;--ink:#1f2328;--muted:#5b6470;--line:#e3e6ea;--bg:#f6f7f9}
*{box-sizing:border-box}
body{font-family:system-ui,-apple-system,'Segoe UI',Roboto,'DejaVu Sans',sans-serif;margin:0;
color:var(--ink);line-height:1.5;background:var(--bg)}
header{background:#0f2a44;color:#fff;padding:1.4em 0 1.2em}
header .in,main{max-width:1120px;margin:0 auto;padding:0 1.2em}
header h1{margin:0;font-size:1.55em;font-weight:650}header p{margin:.2em 0 0;color:#c9d6e3}
nav{position:sticky;top:0;background:#fff;border-bottom:1px solid var(--line);z-index:2}
nav .in{max-width:1120px;margin:0 auto;padding:.45em 1.2em;font-size:.9em}
nav a{color:#0f4c81;text-decoration:none;margin-right:1.1em}nav a.off{color:#9aa3ad}
.summary{display:grid;grid-template-columns:repeat(auto-fit,minmax(170px,1fr));gap:.8em;
margin:1.2em 0}
.card{background:#fff;border:1px solid var(--line);border-left:4px solid #0f4c81;
border-radius:6px;padding:.65em .9em}
.card .l{font-size:.78em;color:var(--muted);text-transform:uppercase;letter-spacing:.03em}
.card .v{font-size:1.25em;font-weight:650;margin:.1em 0}.card .n{font-size:.8em;color:var(--muted)}
.card.ok{border-left-color:#2f855a}.card.warn{border-left-color:#d69e2e}
.card.bad{border-left-color:#c53030}
section{background:#fff;border:1px solid var(--line);border-radius:8px;padding:.3em 1.3em 1em;
margin:1.2em 0}
h2{font-size:1.25em;border-bottom:2px solid var(--accent);padding-bottom:.2em}
figure{margin:1.2em 0}figure img{max-width:100%;display:block;margin:0 auto}
figcaption{font-size:.86em;color:var(--muted);margin-top:.35em}
.twrap{overflow-x:auto}table{border-collapse:collapse;margin:1em 0;font-size:.86em}
th,td{border-bottom:1px solid var(--line);padding:.3em .7em;text-align:right;
font-variant-numeric:tabular-nums}
th{background:#f0f2f5;text-align:right}td:first-child,th:first-child{text-align:left}
tbody tr:nth-child(even){background:#fafbfc}
#table-provenance td,#table-provenance th,#table-dropped td,#table-dropped th{text-align:left}
#table-provenance td:last-child{word-break:break-word;max-width:760px}
caption{text-align:left;font-weight:650;margin-bottom:.35em}.tnote{font-size:.8em;
color:var(--muted);margin-top:-.6em}
.notrun{background:#fff8e6;border:1px solid #f3d58a;border-radius:6px;padding:.6em .9em;
margin:.8em 0;font-size:.92em}
footer{color:var(--muted);font-size:.8em;text-align:center;padding:1.5em}
"""


def render(title: str, subtitle: str, cards: list[Card], sections: list[Section],
           footer: str = "") -> str:
    nav = " ".join(f'<a href="#{s.anchor}"{"" if s.ran else " class=off"}>{esc(s.title)}</a>'
                   for s in sections)
    card_html = "".join(
        f'<div class="card {esc(c.tone)}"><div class="l">{esc(c.label)}</div>'
        f'<div class="v">{esc(c.value)}</div><div class="n">{esc(c.note)}</div></div>'
        for c in cards)
    body = "".join(f'<section id="{s.anchor}"><h2>{esc(s.title)}</h2>'
                   + "".join(s.blocks) + "</section>" for s in sections)
    return ("<!DOCTYPE html><html lang=\"en\"><head><meta charset=\"utf-8\"/>"
            "<meta name=\"viewport\" content=\"width=device-width,initial-scale=1\"/>"
            f"<title>{esc(title)}</title><style>{CSS}</style></head><body>"
            f'<header><div class="in"><h1>{esc(title)}</h1><p>{esc(subtitle)}</p></div></header>'
            f'<nav><div class="in">{nav}</div></nav><main>'
            f'<div class="summary" id="summary">{card_html}</div>{body}</main>'
            f"<footer>{esc(footer)}</footer></body></html>")

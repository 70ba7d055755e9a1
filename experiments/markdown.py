"""The small markdown subset rtfit writes (paragraphs, **bold**, *italic*, `code`, bullet lists,
links, headings), to HTML: escaped, deterministic, no dependency. Inline ``$math$`` is left as text;
links other than http(s), mailto, anchors and relative paths render as plain text."""

from __future__ import annotations

import html
import re

__all__ = ["INLINE", "escape", "markdown_inline", "markdown_text", "markdown_to_html"]

INLINE = re.compile(
    r"(?P<esc>\\[\\`*_{}\[\]()#+\-.!$|<>])"
    r"|(?P<tick>`+)(?P<code>.+?)(?P=tick)"
    r"|(?P<math>\$(?![\s$])[^$\n]*?(?<![\s\\])\$)"
    r"|\[(?P<ltext>[^\]\n]+)\]\((?P<lurl>[^)\s]+)\)"
    r"|<(?P<auto>https?://[^>\s]+)>"
    r"|\*\*(?P<strong>(?!\s).+?(?<!\s))\*\*"
    r"|\*(?P<em>(?![\s*])[^*\n]+?(?<!\s))\*"
)
_SAFE_URL = re.compile(r"^(https?://|mailto:|#|[^:/?#]+(?:[/?#]|$)|/(?!/))", re.I)


def markdown_text(text) -> str:
    """Plain text for markdown output: characters markdown would interpret are backslash-escaped
    (``markdown_inline`` undoes the escapes, so the same text also renders right in HTML)."""
    return re.sub(r"([\\`*\[\]|<>$])", r"\\\1", str(text)).replace("\n", " ")


def escape(text) -> str:
    return html.escape(str(text), quote=True)


def markdown_inline(text: str) -> str:
    """Inline markdown → HTML: **bold**, *italic*, `code`, [links](url), <autolinks>, \\escapes.

    Everything else is escaped; inline math (``$…$``) is left as text in a ``span.math``. Links to
    other schemes than http(s)/mailto/relative paths (``javascript:`` …) render as plain text.
    """
    out, pos = [], 0
    for m in INLINE.finditer(text):
        out.append(escape(text[pos : m.start()]))
        pos = m.end()
        g = m.lastgroup
        if m.group("esc"):
            out.append(escape(m.group("esc")[1]))
        elif m.group("tick"):
            out.append(f"<code>{escape(m.group('code').strip())}</code>")
        elif m.group("math"):
            out.append(f'<span class="math">{escape(m.group("math"))}</span>')
        elif m.group("ltext") is not None:
            url = m.group("lurl")
            inner = markdown_inline(m.group("ltext"))
            out.append(f'<a href="{escape(url)}">{inner}</a>' if _SAFE_URL.match(url) else inner)
        elif m.group("auto"):
            out.append(f'<a href="{escape(m.group("auto"))}">{escape(m.group("auto"))}</a>')
        elif g == "strong":
            out.append(f"<strong>{markdown_inline(m.group('strong'))}</strong>")
        else:
            out.append(f"<em>{markdown_inline(m.group('em'))}</em>")
    out.append(escape(text[pos:]))
    return "".join(out)


_BULLET = re.compile(r"^ {0,3}([-*+]|\d{1,9}[.)])\s+(.*)$")
_HEADING = re.compile(r"^ {0,3}(#{1,6})\s+(.*?)\s*#*\s*$")


def markdown_to_html(text: str, heading_offset: int = 2) -> str:
    """Block markdown → HTML: paragraphs, bullet and numbered lists (one level, lazy continuation
    lines), ``#`` headings (shifted down by ``heading_offset``, at most h6), fenced code blocks;
    inline elements by :func:`markdown_inline`."""
    out: list[str] = []
    para: list[str] = []
    items: list[list[str]] = []
    list_tag = ""

    def flush_para():
        if para:
            out.append(f"<p>{markdown_inline(' '.join(s.strip() for s in para))}</p>")
            para.clear()

    def flush_list():
        nonlocal list_tag
        if items:
            lis = "".join(f"<li>{markdown_inline(' '.join(s.strip() for s in it))}</li>" for it in items)
            out.append(f"<{list_tag}>{lis}</{list_tag}>")
            items.clear()
        list_tag = ""

    lines = text.replace("\r\n", "\n").split("\n")
    i = 0
    while i < len(lines):
        line = lines[i]
        if line.lstrip().startswith("```"):
            flush_para()
            flush_list()
            body = []
            i += 1
            while i < len(lines) and not lines[i].lstrip().startswith("```"):
                body.append(lines[i])
                i += 1
            out.append(f"<pre><code>{escape(chr(10).join(body))}</code></pre>")
        elif not line.strip():
            flush_para()
            flush_list()
        elif h := _HEADING.match(line):
            flush_para()
            flush_list()
            level = min(6, len(h.group(1)) + heading_offset)
            out.append(f"<h{level}>{markdown_inline(h.group(2))}</h{level}>")
        elif b := _BULLET.match(line):
            flush_para()
            tag = "ul" if b.group(1) in "-*+" else "ol"
            if items and tag != list_tag:
                flush_list()
            list_tag = tag
            items.append([b.group(2)])
        elif items:
            items[-1].append(line)
        else:
            para.append(line)
        i += 1
    flush_para()
    flush_list()
    return "\n".join(out)

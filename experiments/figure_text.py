"""The figures' text (`figures.MosaicFigure`): lines drawn by matplotlib's FreeType font as matplotlib draws
them, each line once (`line_pixels`, memoised), composed into labels (`text_pixels`) and wrapped at spaces
to a tile's width (`wrap_to_width`) with as few drawings as the greedy breaks need (issue 33: drawing every
candidate line was most of an audit's figure time)."""

from __future__ import annotations

import threading
from collections import OrderedDict

import numpy as np

PNG_DPI = 110
"""Pixels per inch of the PNG figures."""


def wrap_to_width(text: str, size_pt: float, width_px: float) -> str:
    """``text`` with each of its lines broken at spaces (greedily) so that every line drawn at ``size_pt``
    (`text_pixels`) is at most ``width_px`` figure pixels wide; a single word wider than that keeps a line
    of its own.

    Greedy: each line takes the most words that fit. A line's width grows with the words it takes (its
    glyphs keep their places as words are appended: FreeType lays a line out left to right), so a line
    that fits whole is measured once, and otherwise the most words that fit are found by a search over
    the candidate lines (`_most_words_that_fit`) rather than by measuring one candidate per word: each
    measurement is a drawing (`line_pixels`, memoised), and FreeType's layout of every candidate line was
    a third of an audit's figure time (issue 33)."""
    out = []
    for line in text.split("\n"):
        words = line.split(" ")
        if "" in words:  # (a leading or double space: word by word, each candidate measured)
            current = ""
            for word in words:
                candidate = f"{current} {word}" if current else word
                if current and line_pixels(candidate, size_pt)[0].shape[1] > width_px:
                    out.append(current)
                    current = word
                else:
                    current = candidate
            out.append(current)
            continue
        while len(words) > 1:
            k = _most_words_that_fit(words, size_pt, width_px)
            if k == len(words):
                break
            out.append(" ".join(words[:k]))
            words = words[k:]
        out.append(" ".join(words))
    return "\n".join(out)


def _most_words_that_fit(words: list[str], size_pt: float, width_px: float) -> int:
    """The most leading ``words`` (at least one) whose line is at most ``width_px`` wide at ``size_pt``.

    Only measurements (`line_pixels`) decide, and a line's width grows with the words it takes, so the
    answer is the greedy one: the search keeps lo (lo words fit, or lo = 1) and hi (hi + 1 words do not
    fit, or hi = all) and measures candidates between them until they meet. What it measures first is
    guessed from the characters' advances (`_advances`): the whole line where the guess says it fits
    (one measurement, the line kept), else the guessed k words and then k + 1 (two measurements, the
    first the line kept), bisecting only where the guess was off by more than one word; a line measured
    whole that does not fit guesses again from its glyphs' pen positions."""
    n = len(words)
    advance, mean = _advances(size_pt)
    ends = np.cumsum([sum(advance.get(c, mean) for c in w) + advance.get(" ", mean) for w in words])
    guess = int(np.searchsorted(ends - advance.get(" ", mean), width_px, side="right"))
    lo, hi, steps = 1, n, 0
    while lo < hi:
        probe = (lo + hi + 1) // 2 if guess is None else min(max(guess, lo + 1), hi)
        img, _, pen = line_pixels(" ".join(words[:probe]), size_pt)
        if img.shape[1] <= width_px:
            lo, guess = probe, probe + 1
        else:
            hi, guess = probe - 1, probe - 1
            if probe == n and len(pen) == sum(len(w) for w in words) + n - 1:  # pen x at each space
                spaces = np.cumsum([len(w) + 1 for w in words[:-1]]) - 1
                guess = max(1, int(np.searchsorted(pen[spaces] - pen[0], width_px, side="right")))
                steps = -1
        steps += 1
        if steps >= 3:  # (the guess was off by more than one word: bisect)
            guess = None
    return lo


ADVANCE_SAMPLE = "".join(chr(c) for c in range(32, 127))
"""The characters whose advances `_advances` measures (printable ASCII)."""


def _advances(size_pt: float) -> tuple[dict[str, float], float]:
    """({character: its advance in pixels}, their mean) at ``size_pt``, from the pen positions of one line
    of `ADVANCE_SAMPLE` (`line_pixels`): the guesses of `_most_words_that_fit`, which only orders its
    measurements."""
    _, _, pen = line_pixels(ADVANCE_SAMPLE, size_pt)
    if len(pen) != len(ADVANCE_SAMPLE):
        return {}, 0.6 * size_pt * PNG_DPI / 72
    steps = np.diff(pen)
    return dict(zip(ADVANCE_SAMPLE, steps, strict=False)), float(np.mean(steps))


TEXT_MEMO_BYTES = 16 << 20
"""Bytes of drawn text lines kept (`line_pixels`; a 9 pt label line of 200 pixels is ~3 KB)."""
_text_lock = threading.Lock()
_text_memo: OrderedDict[tuple, tuple[np.ndarray, float, np.ndarray]] = OrderedDict()
_text_bytes = [0]  # (the bytes of the arrays in _text_memo)
MEMOS = (_text_memo,)
"""This module's process-wide memos, emptied between the experiments of a suite (`runner.forget_memos`)."""


def _text_font(size_pt: float) -> tuple:
    """(font file, FreeType load flags, antialiased) of matplotlib's text at ``size_pt``: its default
    family's font and the hinting and antialiasing of its rc settings (as its Agg renderer reads them)."""
    import matplotlib
    from matplotlib.font_manager import FontProperties, findfont
    from matplotlib.ft2font import LoadFlags

    hinting = matplotlib.rcParams["text.hinting"]
    flags = {"default": LoadFlags.DEFAULT, "either": LoadFlags.DEFAULT, "no_autohint": LoadFlags.NO_AUTOHINT,
             "native": LoadFlags.NO_AUTOHINT, "no_hinting": LoadFlags.NO_HINTING,
             "none": LoadFlags.NO_HINTING,
             False: LoadFlags.NO_HINTING}.get(hinting, LoadFlags.FORCE_AUTOHINT)  # fmt: skip
    return findfont(FontProperties(size=size_pt)), flags, bool(matplotlib.rcParams["text.antialiased"])


def line_pixels(line: str, size_pt: float) -> tuple[np.ndarray, float, np.ndarray]:
    """(coverage 0–255 as uint8 (rows, columns), descent in pixels, each glyph's pen x in pixels) of one line
    of text drawn by FreeType (`_text_font`) at ``size_pt`` points and `PNG_DPI`: matplotlib's own drawing
    of it. Memoised by the line, size and font settings (up to `TEXT_MEMO_BYTES`): FreeType's layout of a
    line (``set_text``, some 20–50 µs a glyph) was most of a report's figure time, its labels measured
    again for every candidate line of `wrap_to_width` and drawn again in `text_pixels` (issue 33). The
    arrays are read-only: a caller cannot change the memo."""
    from matplotlib.font_manager import get_font

    path, flags, antialiased = _text_font(size_pt)
    key = (line, float(size_pt), str(path), getattr(path, "face_index", 0), int(flags.value), antialiased)
    with _text_lock:
        hit = _text_memo.get(key)
        if hit is not None:
            _text_memo.move_to_end(key)
            return hit
    font = get_font(path)
    font.clear()
    font.set_size(size_pt, PNG_DPI)
    pen = np.array(font.set_text(line, 0.0, flags=flags), dtype=np.float64).reshape(-1, 2)[:, 0] / 64.0
    font.draw_glyphs_to_bitmap(antialiased=antialiased)
    img = np.array(font.get_image(), dtype=np.uint8)
    img.flags.writeable = pen.flags.writeable = False
    drawn = (img, font.get_descent() / 64.0, pen)
    with _text_lock:
        if not _text_memo:  # (emptied: `runner.forget_memos`)
            _text_bytes[0] = 0
        _text_memo[key] = drawn
        _text_bytes[0] += img.nbytes + pen.nbytes
        while _text_bytes[0] > TEXT_MEMO_BYTES and len(_text_memo) > 1:
            old, _, old_pen = _text_memo.popitem(last=False)[1]
            _text_bytes[0] -= old.nbytes + old_pen.nbytes
    return drawn


def text_pixels(text: str, size_pt: float, ha: str = "center") -> np.ndarray:
    """Coverage in [0, 1] of ``text`` (lines ``ha``-aligned: "center" or "left") drawn by matplotlib's
    FreeType font of its default family at ``size_pt`` points and `PNG_DPI`, with matplotlib's hinting and
    line spacing (1.2). Its lines are drawn by `line_pixels` (memoised); the array returned is the
    caller's own."""
    lp, lp_descent, _ = line_pixels("lp", size_pt)
    ascent, pitch = lp.shape[0] - lp_descent, 1.2 * lp.shape[0]
    lines = [line_pixels(s, size_pt)[:2] for s in text.split("\n")]
    width = max(img.shape[1] for img, _ in lines)
    height = round((len(lines) - 1) * pitch + lp.shape[0]) + 2
    out = np.zeros((height, width))
    for k, (img, descent) in enumerate(lines):
        baseline = k * pitch + ascent
        top = max(0, round(baseline - (img.shape[0] - descent)))
        left = (width - img.shape[1]) // 2 if ha == "center" else 0
        block = img[: height - top] / 255.0
        out[top : top + block.shape[0], left : left + img.shape[1]] = np.maximum(
            out[top : top + block.shape[0], left : left + img.shape[1]], block
        )
    return out

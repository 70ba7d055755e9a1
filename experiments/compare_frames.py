"""The frames and AOVs a user's engine rendered, as ``rtfit compare`` reads them
(`rtfit.experiments.compare`).

* OpenEXR (the ``OpenEXR`` package): the ``R, G, B`` channels (half or float), or a named layer's
  (``FRAME.exr:layer`` reads ``layer.R, layer.G, layer.B``), or one grey ``Y`` channel; linear values as
  stored.
* PNG (matplotlib's reader, Pillow): 8- or 16-bit grey, RGB or RGBA; the sRGB transfer function
  (IEC 61966-2-1) is decoded to linear values, and the report says so
  (an LDR frame is also clipped to [0, 1] by its format).
* Radiance RGBE (``.hdr``) and PFM (``.pfm``) through Mitsuba's ``Bitmap``: linear values.
* A depth AOV (``--aov depth=D.exr``): one channel of an EXR (``Z``, ``depth``, ``Y``, ``R`` or its only one).

Anything unreadable, of another format, without the channels asked for or with values that are not finite is
one `AuditError` line naming the file, read before anything renders.
"""

from __future__ import annotations

import re
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from rtfit.reference.variants import scoped_variant

from .audit import AuditError

__all__ = ["Frame", "frame_id", "read_depth", "read_frame", "split_layer", "srgb_to_linear"]

EXR_SUFFIXES = (".exr",)
PNG_SUFFIXES = (".png",)
HDR_SUFFIXES = (".hdr", ".pfm")


@dataclass(frozen=True)
class Frame:
    """One frame: ``source`` as given (``path[:layer]``), ``path``, ``layer`` (or None), ``image`` (H, W, 3)
    float64 linear RGB, ``encoding`` (words: file format, bit depth, transfer function)."""

    source: str
    path: Path
    layer: str | None
    image: np.ndarray
    encoding: str
    precision: np.ndarray | None = None
    """(H, W, 3) standard deviation of the format's rounding in linear units (a uniform error over one step:
    step/√12): 8- or 16-bit sRGB steps, half floats' 11-bit and RGBE's 8-bit mantissas; None: negligible
    (32-bit floats). It joins the reference's σ where the frame is compared."""


def split_layer(text: str) -> tuple[Path, str | None]:
    """``FRAME.exr:layer`` → (path, layer); a path without a ``:layer`` tail → (path, None)."""
    head, sep, tail = str(text).rpartition(":")
    if sep and head.lower().endswith(EXR_SUFFIXES) and tail and "/" not in tail:
        return Path(head), tail
    return Path(text), None


def frame_id(frame: Frame, taken: set[str]) -> str:
    """A file-name-safe id for ``frame`` (its stem and layer), unique among ``taken`` (added to it)."""
    base = (
        re.sub(r"[^A-Za-z0-9_.-]+", "-", frame.path.stem + (f"-{frame.layer}" if frame.layer else ""))
        or "frame"
    )
    fid, k = base, 2
    while fid in taken:
        fid, k = f"{base}-{k}", k + 1
    taken.add(fid)
    return fid


def srgb_to_linear(v: np.ndarray) -> np.ndarray:
    """The sRGB transfer function (IEC 61966-2-1) decoded: encoded values in [0, 1] → linear."""
    v = np.asarray(v, np.float64)
    return np.where(v <= 0.04045, v / 12.92, ((v + 0.055) / 1.055) ** 2.4)


def _exr_channels(path: Path, what: str) -> dict[str, np.ndarray]:
    import OpenEXR

    try:
        with OpenEXR.File(str(path), separate_channels=True) as f:
            out = {}
            for name, chan in f.channels().items():
                a = np.asarray(chan.pixels)
                if a.ndim != 2:
                    raise AuditError(f"{what} {path}: channel {name!r} is not a 2-D image")
                out[name] = a
            return out
    except AuditError:
        raise
    except Exception as e:  # OpenEXR raises RuntimeError/OSError/… with a message of its own
        raise AuditError(
            f"{what} {path}: not a readable OpenEXR file ({' '.join(str(e).split())[:120]})"
        ) from None


def _bits(a: np.ndarray) -> str:
    return {np.float16: "16-bit half", np.float32: "32-bit float", np.uint32: "32-bit uint"}.get(
        a.dtype.type, str(a.dtype)
    )


def _check_file(path: Path, what: str) -> None:
    if not path.exists():
        raise AuditError(f"{what} {path}: no such file")
    if not path.is_file():
        raise AuditError(f"{what} {path}: not a file")


def _finite(img: np.ndarray, source: str, what: str) -> np.ndarray:
    bad = ~np.isfinite(img)
    if bad.any():
        n = int(bad.any(axis=-1).sum()) if img.ndim == 3 else int(bad.sum())
        raise AuditError(f"{what} {source}: {n} pixel(s) are not finite (NaN or Inf)")
    return img


def read_frame(text: str) -> Frame:
    """The frame ``text`` (``path`` or ``path.exr:layer``) as a `Frame`, or `AuditError` (one line)."""
    path, layer = split_layer(text)
    _check_file(path, "frame")
    suffix = path.suffix.lower()
    if suffix in EXR_SUFFIXES:
        ch = _exr_channels(path, "frame")
        prefix = f"{layer}." if layer else ""
        names = [f"{prefix}{c}" for c in "RGB"]
        if all(n in ch for n in names):
            parts = [ch[n] for n in names]
        elif f"{prefix}Y" in ch:
            parts = [ch[f"{prefix}Y"]] * 3
        else:
            layers = sorted({n.rsplit(".", 1)[0] for n in ch if "." in n})
            hint = f"; its layers: {', '.join(layers)} (FRAME.exr:layer)" if layers else ""
            raise AuditError(
                f"frame {text}: no {'layer ' + repr(layer) + ' with ' if layer else ''}R, G, B (or Y) "
                "channels "
                f"(it has {', '.join(sorted(ch)[:8])}{'…' if len(ch) > 8 else ''}){hint}"
            )
        img = np.stack([np.asarray(p, np.float64) for p in parts], axis=-1)
        enc = f"OpenEXR {_bits(parts[0])}, linear" + (f", layer {layer!r}" if layer else "")
        half = parts[0].dtype == np.float16  # 10 stored mantissa bits: a step of 2^(e − 10)
        prec = _float_step(img, 10) if half else None
        return Frame(text, path, layer, _finite(img, text, "frame"), enc, prec)
    if layer is not None:
        raise AuditError(f"frame {text}: a layer is read from an OpenEXR file only")
    if suffix in PNG_SUFFIXES:
        return _read_png(path, text)
    if suffix in HDR_SUFFIXES:
        return _read_hdr(path, text, suffix)
    raise AuditError(
        f"frame {text}: unsupported format {suffix or '(no suffix)'!r} "
        "(OpenEXR .exr, PNG .png, Radiance .hdr or .pfm)"
    )


def _read_hdr(path: Path, text: str, suffix: str) -> Frame:
    """A Radiance RGBE (.hdr) or PFM frame through Mitsuba's `Bitmap`: linear values (RGBE: 8-bit mantissas
    with a shared exponent, ≈ 1 % steps)."""
    with scoped_variant("scalar_rgb") as mi:
        try:
            bitmap = mi.Bitmap(str(path))
        except Exception as e:  # Mitsuba's RuntimeError with its own message
            raise AuditError(
                f"frame {text}: not a readable {suffix} file ({' '.join(str(e).split())[:120]})"
            ) from None
        a = np.array(bitmap, dtype=np.float64)
        gamma = bool(bitmap.srgb_gamma())
    if a.ndim == 2:
        a = a[..., None]
    if a.shape[-1] == 1:
        a = np.repeat(a, 3, axis=-1)
    img = srgb_to_linear(a[..., :3]) if gamma else a[..., :3]
    what = "Radiance RGBE (8-bit mantissas, shared exponent)" if suffix == ".hdr" else "PFM 32-bit float"
    prec = None
    if (
        suffix == ".hdr"
    ):  # one exponent per pixel, from its largest channel: a step of 2^(e − 8) for all three
        peak = np.max(np.abs(img), axis=-1, keepdims=True)
        prec = np.repeat(_float_step(peak, 7), 3, axis=-1)
    return Frame(text, path, None, _finite(img, text, "frame"), f"{what}, linear", prec)


def _read_png(path: Path, text: str) -> Frame:
    """A PNG through matplotlib's reader (Pillow): 8- or 16-bit values scaled to [0, 1], then sRGB decoded."""
    from matplotlib import image as mpimg

    try:
        a = np.asarray(mpimg.imread(path, format="png"), np.float64)
    except Exception as e:  # Pillow's UnidentifiedImageError, OSError, ValueError, SyntaxError …
        raise AuditError(f"frame {text}: not a readable PNG ({' '.join(str(e).split())[:120]})") from None
    if a.ndim == 2:
        a = np.repeat(a[..., None], 3, axis=-1)
    elif a.ndim == 3 and a.shape[-1] in (3, 4):
        a = a[..., :3]
    elif a.ndim == 3 and a.shape[-1] == 2:  # grey + alpha
        a = np.repeat(a[..., :1], 3, axis=-1)
    else:
        raise AuditError(f"frame {text}: PNG of shape {a.shape} (expected grey, RGB or RGBA)")
    a = np.clip(a, 0.0, 1.0)
    levels = 255.0 if np.allclose(a * 255.0, np.round(a * 255.0), atol=1e-4) else 65535.0
    img = srgb_to_linear(a)
    slope = np.where(a <= 0.04045, 1 / 12.92, 2.4 / 1.055 * ((a + 0.055) / 1.055) ** 1.4)  # d linear / d code
    prec = slope / levels / np.sqrt(12.0)
    bits = "8-bit" if levels == 255.0 else "16-bit"
    enc = f"PNG {bits}, sRGB transfer function decoded to linear (LDR: clipped at 1)"
    return Frame(text, path, None, img, enc, prec)


def _float_step(v: np.ndarray, mantissa_bits: int) -> np.ndarray:
    """The rounding error's standard deviation (step/√12) of floats with ``mantissa_bits`` stored bits."""
    e = np.floor(np.log2(np.maximum(np.abs(v), 1e-30)))
    return 2.0 ** (e - mantissa_bits) / np.sqrt(12.0)


DEPTH_CHANNELS = ("Z", "depth", "Depth", "distance", "Y", "R")
"""A depth EXR's channel, the first of these it has (or its only channel)."""


def read_depth(text: str) -> tuple[np.ndarray, str]:
    """The depth AOV ``text`` (an EXR path, optionally ``:channel``) as (H, W) float64 and the channel read;
    non-finite or non-positive values are kept as NaN (no surface); `AuditError` (one line) otherwise."""
    path, channel = split_layer(text)
    _check_file(path, "--aov depth")
    if path.suffix.lower() not in EXR_SUFFIXES:
        raise AuditError(f"--aov depth {text}: expected an OpenEXR file (.exr)")
    ch = _exr_channels(path, "--aov depth")
    if channel is None:
        channel = next((c for c in DEPTH_CHANNELS if c in ch), next(iter(ch)) if len(ch) == 1 else None)
    if channel is None or channel not in ch:
        raise AuditError(
            f"--aov depth {text}: no depth channel ({', '.join(DEPTH_CHANNELS)}; "
            f"it has {', '.join(sorted(ch))}); "
            "name one: D.exr:channel"
        )
    d = np.asarray(ch[channel], np.float64)
    d = np.where(np.isfinite(d) & (d > 0), d, np.nan)
    if not np.isfinite(d).any():
        raise AuditError(f"--aov depth {text}: channel {channel!r} holds no positive finite depth")
    return d, channel

"""The planner's command beside the ego's own controller over an episode, and the ticks in
which the planner intervened: a chart for the video's panels (:mod:`cdf_mj.viz.panel`),
drawn with NumPy and Pillow's text (no matplotlib); also the pixel helpers both share.

:class:`CommandChart`, against time from 0 to the episode's end [s]:

* the planner's **command** [m/s^2] as it acts (``sensing.brake_latency`` late, within the
  ego car's limits: a planner that does not cap the ego reads the car's full acceleration,
  a yes/no planner's brake its full brake), white;
* the acceleration the ego's **own controller** wanted (speed hold and following, without
  the planner) [m/s^2], blue as the ego;
* **intervening** ticks shaded amber: the command below the own controller's by more than
  the tolerance (:func:`cdf_mj.scenario.ego_agent.intervention_tolerance_of`);
* **hard brake** ticks as a red band along the chart's top (the trace's brake flag).

Legends in words with the values at the frame's time, value ticks [m/s^2] at the left,
time ticks [s] below. ::

    chart = CommandChart(replay, width=336, height=154, font_px=13)
    img = chart.draw(t=1.5)     # (154, 336, 3) uint8: the curves up to 1.5 s
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from cdf_mj.viz.overlays import OVERLAY_COLORS
from cdf_mj.viz.replay import Control, Replay

__all__ = ["COMMAND_COLORS", "CommandChart"]


def _rgb255(rgba: tuple[float, ...]) -> tuple[int, int, int]:
    """RGB uint8 values of an RGBA in [0, 1]."""
    r, g, b = (int(v * 255) for v in rgba[:3])
    return r, g, b


#: RGB of what the chart draws, by its legend's words.
COMMAND_COLORS: dict[str, tuple[int, int, int]] = {
    "command": (245, 245, 245),
    "own controller": (90, 190, 255),  # the ego's colour in the side panel's speed chart
    "intervening": (125, 80, 0),  # a shade under the curves
    "hard brake": _rgb255(OVERLAY_COLORS["brake"]),  # the 3D view's braking stripe
}
_BACK, _GRID, _ZERO, _AXIS = 20, 48, 95, 150  # grey levels
_TEXT, _DIM, _WHITE = (220, 220, 220), (150, 150, 150), (235, 235, 235)
Item = tuple[int, int, str, tuple[int, int, int], str]  # x, y, text, rgb, Pillow anchor
_UNIT = "m/s²"  # of the value axis


def _font(px: int) -> Any:
    """Pillow's default font at ``px`` pixels (the bitmap font where it cannot scale)."""
    from PIL import ImageFont

    try:
        return ImageFont.load_default(size=px)
    except TypeError:  # Pillow without FreeType: the fixed bitmap font
        return ImageFont.load_default()


def _write(img: np.ndarray, font: Any, items: list[Item]) -> np.ndarray:
    """``img`` with each ``(x, y, text, rgb, anchor)`` written (Pillow anchors: ``lm``
    left-middle, ``rm`` right-middle, ``mm`` centre); a "²" as a raised small 2 (Pillow's
    default font has no such glyph)."""
    from PIL import Image, ImageDraw

    pil = Image.fromarray(img)
    draw = ImageDraw.Draw(pil)
    for x, y, text, color, anchor in items:
        if "²" not in text or not hasattr(font, "font_variant"):
            draw.text((x, y), text.replace("²", "^2"), fill=color, font=font, anchor=anchor)
            continue
        head, _, tail = text.partition("²")
        small = font.font_variant(size=max(6, round(font.size * 0.7)))
        width = font.getlength(head) + small.getlength("2") + font.getlength(tail)
        left = x - {"l": 0.0, "m": width / 2, "r": width}[anchor[0]]
        at = "l" + anchor[1]
        draw.text((left, y), head, fill=color, font=font, anchor=at)
        left += font.getlength(head)
        draw.text((left, y - round(0.3 * font.size)), "2", fill=color, font=small, anchor=at)
        draw.text((left + small.getlength("2"), y), tail, fill=color, font=font, anchor=at)
    return np.array(pil)


def _polyline(img: np.ndarray, xs: np.ndarray, ys: np.ndarray, color: np.ndarray,
              thick: int = 1) -> None:
    """Straight segments through the points ``(xs[i], ys[i])`` [px] drawn into ``img``
    (``thick`` rows per point, downwards), clipped to the image."""
    h, w = img.shape[:2]
    for i in range(len(xs)):
        xa, xb = xs[i], xs[i + 1] if i + 1 < len(xs) else xs[i]
        ya, yb = ys[i], ys[i + 1] if i + 1 < len(ys) else ys[i]
        n = int(max(abs(xb - xa), abs(yb - ya), 1)) + 1
        px = np.rint(np.linspace(xa, xb, n)).astype(int)
        py = np.rint(np.linspace(ya, yb, n)).astype(int)
        for d in range(thick):
            ok = (px >= 0) & (px < w) & (py + d >= 0) & (py + d < h)
            img[py[ok] + d, px[ok]] = color


def _nice_step(span: float, most: int) -> float:
    """The smallest of 1, 2, 5 x 10^k giving at most ``most`` steps over ``span``."""
    span = max(span, 1e-9)
    for k in range(-3, 6):
        for m in (1.0, 2.0, 5.0):
            step = m * 10.0 ** k
            if span / step <= most:
                return step
    return span


class CommandChart:
    """The planner's command and the ego's own controller's acceleration over an episode,
    intervening ticks shaded, hard-brake ticks marked (see the module docstring).

    Args:
        replay: the episode; its :attr:`~cdf_mj.viz.replay.Replay.control` is drawn.
        width, height: size of the chart's image [px], at least 80 x 60.
        font_px: the text's height [px].
        x_span: the columns ``(x0, x1)`` [px] of t = 0 and of the episode's end, to line the
            time axis up with other charts (default: after the value labels, to the right
            edge less a margin).

    The value axis spans the episode's commands and own accelerations and 0, with a small
    margin; the background, legends and axes are drawn once, each frame reveals the curves
    and marks up to its time.

    Raises:
        ValueError: a replay without a control trace, or a size below 80 x 60 px.
    """

    def __init__(self, replay: Replay, width: int, height: int, font_px: int,
                 x_span: tuple[int, int] | None = None) -> None:
        control = replay.control
        if control is None:
            raise ValueError(f"seed {replay.record.seed}: its trace has no planner command to chart "
                             "(a trace written before commands were kept)")
        if width < 80 or height < 60:
            raise ValueError(f"command chart {width} x {height} px: needs at least 80 x 60 px")
        self.control: Control = control
        self.times = np.asarray(replay.times, dtype=float)  # tick k: times[k] to times[k + 1] [s]
        self.tick = replay.tick
        self.w, self.h = int(width), int(height)
        self.font = _font(font_px)
        self.line = line = round(font_px * 1.35)
        self.pad = pad = max(3, self.w // 60)
        self.end = max(replay.end_time, 1e-6)  # [s] right end of the time axis
        self._value_range()
        label_w = max(round(self.font.getlength(s)) for s in [_UNIT, *(self._label(v) for v, _ in self.ticks)])
        x0, x1 = x_span if x_span is not None else (pad + label_w + 8, self.w - pad - max(2, font_px // 2))
        # Legend rows (from x0, the unit of the values left of the last), the box, the time ticks.
        self.legend, n_rows = self._legend_layout(x0)
        y0 = pad + n_rows * line + max(2, line // 4)
        y1 = self.h - line - 4
        if y1 - y0 < 12:
            raise ValueError(f"command chart {width} x {height} px: too short for its legend at "
                             f"{font_px} px text")
        #: the data box ``(x0, y0, x1, y1)`` [px]: t = 0 at x0, the end at x1, ``hi`` at y0
        self.box = (int(x0), int(y0), int(x1), int(y1))
        self.band = max(3, line // 4)  # [px] rows of the hard-brake band under y0
        self.base = self._background()
        self.full = self._marks_and_curves()

    # ------------------------------------------------------------- pixel mapping
    def _value_range(self) -> None:
        """The value axis [m/s^2]: the data and 0 with a 5 % margin, ticks of 1, 2, 5 x 10^k."""
        c = self.control
        v = np.concatenate([c.command, c.own])
        v = v[np.isfinite(v)]
        lo, hi = min(float(v.min()) if v.size else -1.0, 0.0), max(float(v.max()) if v.size else 1.0, 0.0)
        span = max(hi - lo, 1.0)
        self.lo, self.hi = lo - 0.05 * span, hi + 0.05 * span
        step = _nice_step(self.hi - self.lo, 4)
        first = math.ceil(self.lo / step - 1e-9)
        #: value ticks ``(value [m/s^2], is zero)`` inside the range
        self.ticks = [(k * step, k == 0) for k in range(first, math.floor(self.hi / step + 1e-9) + 1)]

    @staticmethod
    def _label(v: float) -> str:
        return f"{v:g}" if abs(v) > 1e-9 else "0"

    def x_of(self, t: np.ndarray | float) -> np.ndarray:
        """Column [px] of time(s) ``t`` [s] (clipped to the episode)."""
        x0, _, x1, _ = self.box
        return np.rint(x0 + np.clip(np.asarray(t, dtype=float) / self.end, 0.0, 1.0) * (x1 - x0)).astype(int)

    def y_of(self, a: np.ndarray | float) -> np.ndarray:
        """Row [px] of acceleration(s) ``a`` [m/s^2] (clipped to the value axis)."""
        _, y0, _, y1 = self.box
        f = (np.clip(np.asarray(a, dtype=float), self.lo, self.hi) - self.lo) / (self.hi - self.lo)
        return np.rint(y1 - f * (y1 - y0)).astype(int)

    def tick_columns(self, k: int) -> tuple[int, int]:
        """The columns ``[xa, xb)`` [px] tick ``k`` covers (at least one)."""
        xa, xb = (int(x) for x in self.x_of(self.times[k:k + 2]))
        return xa, max(xb, xa + 1)

    # ------------------------------------------------------------- layout and drawing
    def _legend_layout(self, x0: int) -> tuple[list[tuple[int, int, str, str]], int]:
        """``(x, row, kind, words)`` of each legend entry from column ``x0``: the two curves
        (with room for their values), then, from a new row, the two marks; an entry that
        does not fit goes to the next row. Returns the entries and the number of rows."""
        sw, gap, value_w = self._swatch_w(), max(6, self.line // 2), self.font.getlength(" -0.0")
        out: list[tuple[int, int, str, str]] = []
        x, row = x0, 0
        for kind, words in (("curve", "command"), ("curve", "own controller"), ("mark", "intervening"),
                            ("mark", "hard brake")):
            w = sw + self.font.getlength(words) + (value_w if kind == "curve" else 0)
            if out and ((kind == "mark" and out[-1][2] == "curve") or x + w > self.w - self.pad):
                x, row = x0, row + 1
            out.append((round(x), row, kind, words))
            x += w + gap
        return out, row + 1

    def _swatch_w(self) -> int:
        return round(self.line * 1.1) + 4

    def _row_y(self, row: int) -> int:
        return self.pad + row * self.line + self.line // 2

    def _grid(self, img: np.ndarray) -> None:
        """Value and time grid lines, the zero line brighter."""
        x0, y0, x1, y1 = self.box
        for v, zero in self.ticks:
            img[int(self.y_of(v)), x0:x1 + 1] = _ZERO if zero else _GRID
        step = _nice_step(self.end, 6)
        for k in range(int(self.end / step + 1e-9) + 1):
            xx = int(self.x_of(k * step))
            img[y0:y1 + 1, xx] = np.maximum(img[y0:y1 + 1, xx], _GRID)

    def _background(self) -> np.ndarray:
        """Legends, axes, ticks and units: what every frame shares."""
        img = np.full((self.h, self.w, 3), _BACK, dtype=np.uint8)
        x0, y0, x1, y1 = self.box
        items: list[Item] = []
        sw = self._swatch_w() - 4
        for x, row, kind, words in self.legend:
            y, rgb = self._row_y(row), COMMAND_COLORS[words]
            if words == "hard brake":
                img[y - self.band // 2:y - self.band // 2 + self.band, x:x + sw] = rgb
            elif kind == "mark":
                img[y - self.line // 3:y + self.line // 3, x:x + sw] = rgb
            else:
                img[y - 1:y + 1, x:x + sw] = rgb
            items.append((x + sw + 4, y, words, _TEXT, "lm"))
        self._grid(img)
        for v, _ in self.ticks:
            yy = int(self.y_of(v))
            img[yy, x0 - 5:x0 - 1] = _AXIS
            items.append((x0 - 7, yy, self._label(v), _DIM, "rm"))
        img[y0 - 1:y1 + 3, x0 - 2] = _AXIS
        img[y1 + 2, x0 - 2:x1 + 2] = _AXIS
        # Units: the values' above their labels (on the last legend row), the time's at the right.
        items.append((x0 - 7, self._row_y(self.legend[-1][1]), _UNIT, _DIM, "rm"))
        row_t = y1 + 4 + self.line // 2
        step = _nice_step(self.end, 6)
        unit_x = self.w - self.pad - round(self.font.getlength("time [s]"))
        for k in range(int(self.end / step + 1e-9) + 1):
            xx, label = int(self.x_of(k * step)), f"{k * step:g}"
            img[y1 + 2:y1 + 6, xx] = _AXIS
            if xx + self.font.getlength(label) / 2 + self.pad < unit_x:
                items.append((xx, row_t, label, _DIM, "mm"))
        items.append((self.w - self.pad, row_t, "time [s]", _DIM, "rm"))
        return _write(img, self.font, items)

    def _marks_and_curves(self) -> np.ndarray:
        """The whole episode drawn once: shaded intervening ticks, the hard-brake band, the
        grid again, then the own controller's curve and the command's over it."""
        img = self.base.copy()
        c = self.control
        _, y0, _, y1 = self.box
        for k in np.flatnonzero(c.intervening):
            xa, xb = self.tick_columns(int(k))
            img[y0:y1 + 1, xa:xb] = COMMAND_COLORS["intervening"]
        for k in np.flatnonzero(c.brake):
            xa, xb = self.tick_columns(int(k))
            img[y0:y0 + self.band, xa:xb] = COMMAND_COLORS["hard brake"]
        self._grid(img)
        tx = self.x_of(self.times[:len(c.own)])
        for key, values in (("own controller", c.own), ("command", c.command)):
            ok = np.isfinite(values)  # a NaN is a gap: drawn up to it
            for run in np.split(np.flatnonzero(ok), np.flatnonzero(np.diff(np.flatnonzero(ok)) > 1) + 1):
                if run.size:
                    _polyline(img, tx[run], self.y_of(values[run]), np.asarray(COMMAND_COLORS[key], np.uint8),
                              thick=2)
        return img

    def draw(self, t: float) -> np.ndarray:
        """The chart ``(height, width, 3)`` uint8 at time ``t`` [s]: marks and curves up to
        ``t``, a cursor at ``t`` and both values of that tick in the legend."""
        img = self.base.copy()
        x0, y0, _x1, y1 = self.box
        cx = int(self.x_of(t))
        img[y0 - 1:y1 + 2, x0:cx + 1] = self.full[y0 - 1:y1 + 2, x0:cx + 1]
        img[y0:y1 + 1, cx] = np.maximum(img[y0:y1 + 1, cx], 110)  # cursor
        k = min(self.tick(t), len(self.control.own) - 1)
        values = {"command": self.control.command[k], "own controller": self.control.own[k]}
        items: list[Item] = []
        for x, row, kind, words in self.legend:
            if kind == "curve":
                v = values[words]
                at = x + self._swatch_w() + round(self.font.getlength(words + " "))
                items.append((at, self._row_y(row), f"{v:.1f}" if math.isfinite(v) else "-", _WHITE, "lm"))
        return _write(img, self.font, items)

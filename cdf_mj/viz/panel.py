"""The posterior drawn beside or over each frame (NumPy and Pillow's text, no per-frame
matplotlib): :class:`Panel` over the top-left corner of the 3D view, :class:`SidePanel` a
column of readable time series beside it (``cdf-mj render --layout side``).

:class:`Panel` rows, top to bottom: seed, planner and label; the time and, while the ego
brakes hard, BRAKE; the planner's probabilities as bars (P(left), P(seen), P(cutoff) and
the risk for ``cdf``; ``tau`` marked on the last) and as a running plot over the episode
with the braking time; for a planner with particles, the particle colours in words. A
planner without probabilities gets a line saying so. Over the bottom-left corner, in both
layouts, the planner's command beside the ego's own controller's acceleration [m/s^2]
with the ticks in which it intervened shaded and its hard-brake ticks marked
(:class:`~cdf_mj.viz.command_chart.CommandChart`; not for a trace without commands).

:class:`SidePanel`, top to bottom: the head line and the time; a chart of the planner's
probabilities over the episode [0, 1] with its threshold ``tau`` dashed (for a planner
without probabilities, a line saying so); a chart of both cars' speeds [m/s]; both with
the brake decision (red) and the obstacle's entry into the ego's lane (white, dashed) as
vertical lines from the moment they happen, time ticks [s], value ticks and legends in
words; the particle colours in words for a planner with particles. ::

    panel = Panel(replay, width=640, height=480, planner="cdf")
    frame = panel.draw(frame, t=1.5)     # frame (480, 640, 3) uint8, changed in place
    frame = panel.draw_chart(frame, t=1.5)   # the command chart alone (the side layout)
    side = SidePanel(replay, width=360, height=480, planner="cdf")
    column = side.draw(t=1.5)            # (480, 360, 3) uint8, to put beside the frame
"""

from __future__ import annotations

import math

import numpy as np

from cdf_mj.viz.command_chart import CommandChart, Item, _font, _nice_step, _polyline, _write
from cdf_mj.viz.overlays import OVERLAY_COLORS, PARTICLE_COLORS
from cdf_mj.viz.replay import POSTERIOR_KEYS, Replay

__all__ = ["SIDE_MIN_HEIGHT", "Panel", "SidePanel", "particle_legend", "side_width"]

#: The label of each probability of :data:`cdf_mj.viz.replay.POSTERIOR_KEYS`.
_LABELS = {"p_left": "P(left)", "p_seen": "P(seen)", "p_cutoff": "P(cutoff)", "p_conflict": "P(conflict)",
           "risk": "risk"}
#: What each probability means, in the side panel's legend.
_MEANINGS = {"p_left": "turns across the ego's lane", "p_seen": "has seen the ego",
             "p_cutoff": "cuts the ego off", "p_conflict": "paths conflict",
             "risk": "collision unless the ego brakes now"}
#: Smallest frame height [px] the side panel's two charts are laid out for.
SIDE_MIN_HEIGHT = 160
_WHITE, _TEXT, _DIM = (235, 235, 235), (220, 220, 220), (150, 150, 150)
_AXIS, _GRID, _BACK = 150, 48, 20  # grey levels
_SPEED_COLORS = {"ego": (90, 190, 255), "obstacle": (255, 170, 60)}  # the speed chart's curves
_ENTRY = (240, 240, 240)  # the obstacle's lane entry marker


def _rgb(name: str) -> np.ndarray:
    """The RGB uint8 of :data:`~cdf_mj.viz.overlays.OVERLAY_COLORS` ``name``."""
    return (np.asarray(OVERLAY_COLORS[name][:3]) * 255).astype(np.uint8)


def side_width(height: int) -> int:
    """Width [px] of the :class:`SidePanel` beside a frame ``height`` px high: three
    quarters of it, even (MP4 needs even sizes)."""
    return 2 * round(0.375 * height)


def particle_legend() -> list[tuple[tuple[int, int, int], str]]:
    """``(rgb, words)`` of each particle colour of
    :data:`~cdf_mj.viz.overlays.PARTICLE_COLORS`, e.g. ``"left, saw ego"``."""
    out = []
    for (intent, seen), rgba in PARTICLE_COLORS.items():
        r, g, b = (int(v * 255) for v in rgba[:3])
        out.append(((r, g, b), f"{intent}{', saw ego' if seen else ''}"))
    return out


class Panel:
    """Probabilities, their history and a legend over the top-left of each frame, and the
    planner's command beside the ego's own controller over its bottom-left.

    Args:
        replay: the episode; its ``posterior`` chooses the bars and curves, its
            ``particles`` whether the particle colours are explained, its ``control`` the
            command chart (:class:`~cdf_mj.viz.command_chart.CommandChart`; none for a
            trace without it).
        width, height: size of the frames drawn on [px]; the panel takes about 38 % of the
            width and 36 % of the height (at least 48 x 32 px, at most the frame), the
            command chart 55 % of the width and 32 % of the height (where that is at least
            80 x 60 px and below the panel).
        planner: the planner's name, in the head line.
        bottom: rows [px] left free under the command chart (a caption along the frame's
            bottom).

    Needs Pillow (the ``viz`` extra); the background, legend and the curves over the
    whole episode are drawn once, each frame reveals them up to its time.
    """

    ALPHA = 0.82  # opacity of the panel over the scene

    def __init__(self, replay: Replay, width: int, height: int, planner: str, bottom: int = 0) -> None:
        self.replay = replay
        self.w = max(48, round(0.38 * width))
        self.h = max(32, round(0.36 * height))
        self.w, self.h = min(self.w, width), min(self.h, height)
        fs = max(7, round(self.h / 13))
        self.font = _font(fs)
        self.keys = tuple(k for k in POSTERIOR_KEYS if replay.posterior is not None and k in replay.posterior)
        self.legend = particle_legend() if replay.particles is not None else []
        # Rows: 0 head, 1 time and braking, one per bar (at least three), three of the
        # running plot (to the bottom without particles), the last two the particle colours.
        n_bars = max(3, len(self.keys))
        n_rows = 2 + n_bars + 3 + 2
        line = self.h / n_rows
        self.rows = [round(line * (i + 0.5)) for i in range(n_rows)]  # text centres
        self.label_w = round(0.34 * self.w)
        self.bar_x0, self.bar_x1 = self.label_w, round(0.82 * self.w)
        self.bar_h = max(2, round(line * 0.6))
        self.plot = (round(0.04 * self.w), round(line * (2.1 + n_bars)), round(0.96 * self.w),
                     round(line * (n_rows - 2.1 if self.legend else n_rows - 0.4)))  # x0, y0, x1, y1
        head = f"seed {replay.record.seed}  {planner}  label {replay.label or '-'}"
        self.base = self._background(head)
        self.curves = self._curves()
        #: the command chart and its top row [px] in the frame (None: no command to chart,
        #: or no room below the panel)
        self.chart: CommandChart | None = None
        self.chart_y = height - bottom - round(0.32 * height)
        cw, ch = min(width, round(0.55 * width)), round(0.32 * height)
        if replay.control is not None and cw >= 80 and ch >= 60 and self.chart_y >= self.h:
            self.chart = CommandChart(replay, cw, ch, fs)

    def _text(self, img: np.ndarray, items: list[tuple[int, int, str, tuple[int, int, int]]]) -> np.ndarray:
        """``img`` with each ``(x, y, text, rgb)`` written, left end and vertical middle at x, y."""
        return _write(img, self.font, [(x, y, text, rgb, "lm") for x, y, text, rgb in items])

    def _background(self, head: str) -> np.ndarray:
        """What every frame shares: head line, bar labels, legend and the plot's axes."""
        img = np.full((self.h, self.w, 3), _BACK, dtype=np.uint8)
        pad = max(2, self.w // 60)
        items = [(pad, self.rows[0], head, _WHITE)]
        if self.replay.posterior is not None:
            for i, k in enumerate(self.keys):
                r, g, b = (int(v) for v in _rgb(k))
                items.append((pad, self.rows[2 + i], _LABELS[k], (r, g, b)))
        else:
            items.append((pad, self.rows[2], "no filter: planner without a posterior", (200, 200, 200)))
        # The particle colours in words, two to a row.
        sw = max(2, self.bar_h)
        for i, (rgb, words) in enumerate(self.legend):
            x = pad + (i % 2) * (self.w - 2 * pad) // 2
            y = self.rows[-2 + min(i // 2, 1)]
            img[y - sw // 2:y - sw // 2 + sw, x:x + sw] = rgb
            items.append((x + sw + 2, y, words, _TEXT))
        img = self._text(img, items)
        x0, y0, x1, y1 = self.plot
        img[y0:y1 + 1, x0] = 90
        img[y1, x0:x1 + 1] = 90
        return img

    def _curves(self) -> np.ndarray | None:
        """Every curve over the whole episode, drawn once; frames reveal columns."""
        post = self.replay.posterior
        if post is None:
            return None
        x0, _y0, x1, _y1 = self.plot
        img = self.base.copy()
        tx = self._x(post["t"])
        if self.replay.tau is not None:
            ty = self._y(self.replay.tau)
            img[ty, x0:x1 + 1:3] = _rgb(self.keys[-1]) // 2
        for k in self.keys:
            _polyline(img, tx, self._y(post[k]), _rgb(k))
        return img

    def _x(self, t: np.ndarray | float) -> np.ndarray:
        """Plot column [px] of time(s) ``t`` [s]."""
        x0, _, x1, _ = self.plot
        end = max(self.replay.end_time, 1e-6)
        return np.rint(x0 + 1 + np.clip(np.asarray(t) / end, 0.0, 1.0) * (x1 - x0 - 1)).astype(int)

    def _y(self, p: np.ndarray | float) -> np.ndarray:
        """Plot row [px] of probability(ies) ``p``."""
        _, y0, _, y1 = self.plot
        return np.rint(y1 - 1 - np.clip(np.asarray(p), 0.0, 1.0) * (y1 - y0 - 2)).astype(int)

    def draw(self, frame: np.ndarray, t: float) -> np.ndarray:
        """The panel at time ``t`` blended into ``frame`` (in place); returns ``frame``."""
        rep = self.replay
        img = self.base.copy()
        x0, y0, _x1, y1 = self.plot
        cx = int(self._x(t))
        if self.curves is not None:
            img[y0:y1, x0:cx + 1] = self.curves[y0:y1, x0:cx + 1]
        img[y0:y1, cx] = 160  # cursor
        pad = max(2, self.w // 60)
        items = [(pad, self.rows[1], f"t {t:5.2f} s", _WHITE)]
        if rep.record.brake_time is not None and rep.braking(t):
            bx = int(self._x(rep.record.brake_time))
            img[y0:y1, bx] = _rgb("brake")
            bw = round(0.34 * self.w)
            img[self.rows[1] - self.bar_h:self.rows[1] + self.bar_h, self.w - bw - pad:self.w - pad] = _rgb("brake")
            items.append((self.w - bw, self.rows[1], "BRAKE", (255, 255, 255)))
        if rep.posterior is not None:
            k = rep.tick(t)
            span = self.bar_x1 - self.bar_x0
            for i, key in enumerate(self.keys):
                p = float(rep.posterior[key][min(k, len(rep.posterior[key]) - 1)])
                yc = self.rows[2 + i]
                ya, yb = yc - self.bar_h // 2, yc - self.bar_h // 2 + self.bar_h
                img[ya:yb, self.bar_x0:self.bar_x1] = 55
                img[ya:yb, self.bar_x0:self.bar_x0 + round(p * span)] = _rgb(key)
                if key == self.keys[-1] and rep.tau is not None:  # the braking quantity
                    tx = self.bar_x0 + round(rep.tau * span)
                    img[ya - 1:yb + 1, min(tx, self.w - 1)] = 255
                items.append((self.bar_x1 + pad, yc, f"{p:.2f}", _WHITE))
        self._blend(frame, self._text(img, items), 0)
        return self.draw_chart(frame, t)

    def draw_chart(self, frame: np.ndarray, t: float) -> np.ndarray:
        """The command chart alone at time ``t`` blended into ``frame``'s bottom-left (in
        place; nothing without a chart); returns ``frame``. The ``side`` layout draws it so
        over its view, which has no panel."""
        if self.chart is not None:
            self._blend(frame, self.chart.draw(t), self.chart_y)
        return frame

    def _blend(self, frame: np.ndarray, img: np.ndarray, top: int) -> None:
        """``img`` over ``frame`` at its left edge from row ``top``, at :attr:`ALPHA`."""
        region = frame[top:top + img.shape[0], :img.shape[1]]
        region[...] = (self.ALPHA * img + (1.0 - self.ALPHA) * region).astype(np.uint8)


class SidePanel:
    """Readable time series of an episode, drawn as a column to put beside each frame.

    Args:
        replay: the episode: its ``posterior`` (and ``tau``) give the probability chart,
            its poses the speed chart, its record the brake decision and the lane entry
            (``entered_lane_time``, where the record has one), its ``particles`` whether
            the particle colours are explained.
        width, height: size of the column [px] (:func:`side_width` gives the width used
            beside a frame); ``height`` at least :data:`SIDE_MIN_HEIGHT`.
        planner: the planner's name, in the head line and in the note of a planner
            without probabilities.

    Both charts share the time axis, 0 at the left to the episode's end at the right
    [s]. The background, axes, legends and curves are drawn once; each frame reveals the
    curves up to its time and writes the values of that time.

    Raises:
        ValueError: ``height`` below :data:`SIDE_MIN_HEIGHT` or ``width`` below 80 px.
    """

    def __init__(self, replay: Replay, width: int, height: int, planner: str) -> None:
        if height < SIDE_MIN_HEIGHT:
            raise ValueError(f"--height {height}: the side panel's charts need at least "
                             f"{SIDE_MIN_HEIGHT} px")
        if width < 80:
            raise ValueError(f"side panel width {width} px: needs at least 80 px")
        self.replay, self.planner = replay, planner
        self.w, self.h = int(width), int(height)
        fs = max(8, min(18, round(height / 30)))
        self.font = _font(fs)
        self.line = line = round(fs * 1.35)
        pad = self.pad = max(3, self.w // 40)
        post = replay.posterior
        self.keys = tuple(k for k in POSTERIOR_KEYS if post is not None and k in post)
        self.legend = particle_legend() if replay.particles is not None else []
        rec = replay.record
        self.brake_time: float | None = rec.brake_time
        self.entry_time: float | None = getattr(rec, "entered_lane_time", None)
        self.end = max(replay.end_time, 1e-6)  # [s] right end of the time axis
        speeds = np.asarray(replay.poses, dtype=float)[:, :, 3]
        top = float(np.nanmax(speeds)) if speeds.size else 1.0
        step = _nice_step(max(top, 1.0) * 1.05, 4)
        #: top of the speed axis [m/s]: the fastest speed, rounded up to a tick
        self.speed_max = step * math.ceil(max(top, 1.0) * 1.05 / step)
        self.speed_step = step

        # Vertical layout (text lines of height `line` and the two plot boxes).
        y = pad
        self.row_head, self.row_time = y + line // 2, y + line + line // 2
        y += 2 * line
        n_prob_lines = (len(self.keys) + (replay.tau is not None)) if self.keys else 1
        self.rows_prob = [y + line * i + line // 2 for i in range(n_prob_lines)]
        y += n_prob_lines * line + line // 3
        fixed_below = line * (1 + 1 + 2 + (2 if self.legend else 0)) + pad  # speed legend,
        free = self.h - y - fixed_below - 4                                  # ticks, markers
        margin_l = pad + round(fs * 1.9)
        margin_r = self.w - pad - round(fs * 0.6)
        if self.keys:
            h_prob = max(10, round(0.55 * free))
            self.prob_box: tuple[int, int, int, int] | None = (margin_l, y + 2, margin_r, y + 2 + h_prob)
            y += h_prob + 4
        else:
            self.prob_box = None
        self.row_speed = y + line // 2
        y += line
        h_speed = max(10, self.h - y - (fixed_below - line) - 2)
        #: the speed chart's data box ``(x0, y0, x1, y1)`` [px]: t = 0 at x0, ``end`` at x1,
        #: 0 m/s at y1, :attr:`speed_max` at y0
        self.speed_box = (margin_l, y + 2, margin_r, y + 2 + h_speed)
        y += h_speed + 4
        self.row_ticks = y + line // 2
        y += line
        self.rows_marks = [y + line // 2, y + line + line // 2]
        y += 2 * line
        self.rows_legend = [y + line // 2, y + line + line // 2]
        head = f"seed {rec.seed}  {planner}  {replay.label or ''}".rstrip()
        self.base = self._background(head)
        self.curves = self._curves()

    # ------------------------------------------------------------- pixel mapping
    def x_of(self, t: np.ndarray | float) -> np.ndarray:
        """Column [px] of time(s) ``t`` [s] in both charts (clipped to the episode)."""
        x0, _, x1, _ = self.speed_box
        return np.rint(x0 + np.clip(np.asarray(t, dtype=float) / self.end, 0.0, 1.0) * (x1 - x0)).astype(int)

    @staticmethod
    def _y_in(box: tuple[int, int, int, int], v: np.ndarray | float, top: float) -> np.ndarray:
        _, y0, _, y1 = box
        return np.rint(y1 - np.clip(np.asarray(v, dtype=float) / top, 0.0, 1.0) * (y1 - y0)).astype(int)

    def prob_y(self, p: np.ndarray | float) -> np.ndarray:
        """Row [px] of probability(ies) ``p`` in the probability chart."""
        if self.prob_box is None:
            raise ValueError(f"planner {self.planner!r} has no probabilities to chart")
        return self._y_in(self.prob_box, p, 1.0)

    def speed_y(self, v: np.ndarray | float) -> np.ndarray:
        """Row [px] of speed(s) ``v`` [m/s] in the speed chart."""
        return self._y_in(self.speed_box, v, self.speed_max)

    # ------------------------------------------------------------- drawing
    def _text(self, img: np.ndarray, items: list[Item]) -> np.ndarray:
        """``img`` with each ``(x, y, text, rgb, anchor)`` written."""
        return _write(img, self.font, items)

    def _boxes(self) -> list[tuple[int, int, int, int]]:
        return [b for b in (self.prob_box, self.speed_box) if b is not None]

    def _swatch(self, img: np.ndarray, x: int, y: int, rgb: tuple[int, ...] | np.ndarray,
                dashed: bool = False) -> int:
        """A short line of colour ``rgb`` left at ``x``, centred on row ``y``; returns the
        column after it."""
        n = round(self.line * 1.1)
        cols = np.arange(x, min(x + n, self.w))
        if dashed:
            cols = cols[(cols - x) % 4 < 2]
        img[y - 1:y + 1, cols] = rgb
        return x + n + 4

    def _axes(self, img: np.ndarray, box: tuple[int, int, int, int], ticks: list[tuple[float, str]],
              top: float, items: list[Item]) -> None:
        """Axes just outside ``box``, value ticks with labels at its left, faint grid lines,
        and time ticks at its bottom."""
        x0, y0, x1, y1 = box
        for v, label in ticks:
            yy = int(self._y_in(box, v, top))
            img[yy, x0:x1 + 1] = _GRID
            img[yy, x0 - 5:x0 - 1] = _AXIS
            items.append((x0 - 7, yy, label, _DIM, "rm"))
        step = _nice_step(self.end, 6)
        for k in range(int(self.end / step + 1e-9) + 1):
            xx = int(self.x_of(k * step))
            img[y0:y1 + 1, xx] = np.maximum(img[y0:y1 + 1, xx], _GRID)
            img[y1 + 2:y1 + 6, xx] = _AXIS
        img[y0 - 1:y1 + 3, x0 - 2] = _AXIS
        img[y1 + 2, x0 - 2:x1 + 2] = _AXIS

    def _background(self, head: str) -> np.ndarray:
        """Head line, legends, axes with ticks and units: what every frame shares."""
        img = np.full((self.h, self.w, 3), _BACK, dtype=np.uint8)
        pad = self.pad
        items: list[Item] = [
            (pad, self.row_head, head, _WHITE, "lm")]
        if self.prob_box is not None:
            for key, y in zip(self.keys, self.rows_prob, strict=False):
                x = self._swatch(img, pad, y, _rgb(key))
                items.append((x, y, f"{_LABELS[key]}: {_MEANINGS[key]}", _TEXT, "lm"))
            if self.replay.tau is not None:
                y = self.rows_prob[len(self.keys)]
                x = self._swatch(img, pad, y, _rgb(self.keys[-1]) // 2 + 60, dashed=True)
                items.append((x, y, f"threshold {self.replay.tau:g}: brakes when {_LABELS[self.keys[-1]]} "
                                    "reaches it", _TEXT, "lm"))
            self._axes(img, self.prob_box, [(0.0, "0"), (0.5, "0.5"), (1.0, "1")], 1.0, items)
        else:
            items.append((pad, self.rows_prob[0], f"{self.planner}: no probabilities to chart",
                          _DIM, "lm"))
        x = pad + round(self.font.getlength("speed [m/s]")) + 3 * pad
        items.append((pad, self.row_speed, "speed [m/s]", _TEXT, "lm"))
        self.speed_value_x = []  # where each car's speed at the frame's time is written
        for who, rgb in _SPEED_COLORS.items():
            x = self._swatch(img, x, self.row_speed, rgb)
            items.append((x, self.row_speed, who, _TEXT, "lm"))
            x += round(self.font.getlength(who + " "))
            self.speed_value_x.append(x)
            x += round(self.font.getlength("00.0")) + 3 * pad
        n = max(1, round(self.speed_max / self.speed_step))
        ticks = [(i * self.speed_step, f"{i * self.speed_step:g}") for i in range(n + 1)]
        self._axes(img, self.speed_box, ticks, self.speed_max, items)
        step = _nice_step(self.end, 6)
        unit_x = self.w - pad - round(self.font.getlength("time [s]"))  # the unit, right
        for k in range(int(self.end / step + 1e-9) + 1):
            label = f"{k * step:g}"
            xx = int(self.x_of(k * step))
            if xx + self.font.getlength(label) / 2 + pad < unit_x:
                items.append((xx, self.row_ticks, label, _DIM, "mm"))
        items.append((self.w - pad, self.row_ticks, "time [s]", _DIM, "rm"))
        # The two event markers, in words with their times.
        bt, et = self.brake_time, self.entry_time
        x = self._swatch(img, pad, self.rows_marks[0], _rgb("brake"))
        items.append((x, self.rows_marks[0], "brake decision " + (f"at {bt:.2f} s" if bt is not None
                                                                  else ": none"), _TEXT, "lm"))
        x = self._swatch(img, pad, self.rows_marks[1], _ENTRY, dashed=True)
        items.append((x, self.rows_marks[1], "obstacle enters the ego's lane "
                      + (f"at {et:.2f} s" if et is not None else ": never"), _TEXT, "lm"))
        for i, (rgb, words) in enumerate(self.legend):
            xi = pad + (i % 2) * (self.w - 2 * pad) // 2
            yi = self.rows_legend[min(i // 2, 1)]
            s = max(4, self.line // 2)
            img[yi - s // 2:yi - s // 2 + s, xi:xi + s] = rgb
            items.append((xi + s + 4, yi, f"particle: {words}" if i == 0 else words, _TEXT, "lm"))
        return self._text(img, items)

    def _curves(self) -> np.ndarray:
        """Every curve over the whole episode, drawn once; frames reveal columns."""
        img = self.base.copy()
        rep = self.replay
        if self.prob_box is not None and rep.posterior is not None:
            tx = self.x_of(rep.posterior["t"])
            if rep.tau is not None:
                x0, _, x1, _ = self.prob_box
                ty = int(self.prob_y(rep.tau))
                cols = np.arange(x0, x1 + 1)
                img[ty, cols[(cols - x0) % 6 < 3]] = _rgb(self.keys[-1]) // 2 + 60
            for key in self.keys:
                _polyline(img, tx, self.prob_y(rep.posterior[key]), _rgb(key), thick=2)
        tx = self.x_of(rep.times)
        for i, rgb in enumerate(_SPEED_COLORS.values()):
            _polyline(img, tx, self.speed_y(np.asarray(rep.poses, dtype=float)[:, i, 3]),
                      np.asarray(rgb, dtype=np.uint8), thick=2)
        return img

    def _marker(self, img: np.ndarray, t: float, rgb: tuple[int, ...] | np.ndarray, dashed: bool) -> None:
        xx = int(self.x_of(t))
        for _x0, y0, _x1, y1 in self._boxes():
            rows = np.arange(y0 - 1, y1 + 1)
            if dashed:
                rows = rows[(rows - y0) % 6 < 3]
            img[rows, xx] = rgb

    def draw(self, t: float) -> np.ndarray:
        """The column ``(height, width, 3)`` uint8 at time ``t`` [s]: curves up to ``t``, a
        cursor at ``t``, the markers of what has happened by ``t`` and the values at ``t``."""
        rep = self.replay
        img = self.base.copy()
        cx = int(self.x_of(t))
        for x0, y0, _x1, y1 in self._boxes():
            img[y0 - 1:y1 + 1, x0:cx + 1] = self.curves[y0 - 1:y1 + 1, x0:cx + 1]
        if self.entry_time is not None and t + 1e-9 >= self.entry_time:
            self._marker(img, self.entry_time, _ENTRY, dashed=True)
        if self.brake_time is not None and rep.braking(t):
            self._marker(img, self.brake_time, _rgb("brake"), dashed=False)
        for _x0, y0, _x1, y1 in self._boxes():
            img[y0:y1 + 1, cx] = np.maximum(img[y0:y1 + 1, cx], 110)  # cursor
        pad, line = self.pad, self.line
        items: list[Item] = [
            (pad, self.row_time, f"t = {t:5.2f} s", _WHITE, "lm")]
        if rep.braking(t):
            bw = round(0.3 * self.w)
            img[self.row_time - line // 2 + 1:self.row_time + line // 2, self.w - pad - bw:self.w - pad] = _rgb("brake")
            items.append((self.w - pad - bw // 2, self.row_time, "BRAKE", (255, 255, 255), "mm"))
        if self.prob_box is not None and rep.posterior is not None:
            k = rep.tick(t)
            for key, y in zip(self.keys, self.rows_prob, strict=False):
                p = float(rep.posterior[key][min(k, len(rep.posterior[key]) - 1)])
                items.append((self.w - pad, y, f"{p:.2f}", _WHITE, "rm"))
        v = rep.pose_at(t)[:, 3]
        for x, speed in zip(self.speed_value_x, v, strict=True):
            items.append((x, self.row_speed, f"{speed:.1f}", _WHITE, "lm"))
        return self._text(img, items)

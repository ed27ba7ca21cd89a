"""The posterior panel drawn over the top-left corner of each frame (NumPy and Pillow's
text, no per-frame matplotlib).

Rows, top to bottom: seed, planner and label; the time and, once the ego brakes, BRAKE;
the planner's probabilities as bars (P(left), P(seen), P(cutoff) for ``cdf``; ``tau``
marked on the last) and as a running plot over the episode with the braking time; a
legend of the particle colours (:data:`cdf_mj.viz.overlays.PARTICLE_COLORS`). A planner
without probabilities gets a line saying so. ::

    panel = Panel(replay, width=640, height=480, planner="cdf")
    frame = panel.draw(frame, t=1.5)     # frame (480, 640, 3) uint8, changed in place
"""

from __future__ import annotations

from typing import Any

import numpy as np

from cdf_mj.viz.overlays import OVERLAY_COLORS, PARTICLE_COLORS
from cdf_mj.viz.replay import POSTERIOR_KEYS, Replay

__all__ = ["Panel"]

#: The label of each probability of :data:`cdf_mj.viz.replay.POSTERIOR_KEYS`.
_LABELS = {"p_left": "P(left)", "p_seen": "P(seen)", "p_cutoff": "P(cutoff)", "p_conflict": "P(conflict)"}


def _font(px: int) -> Any:
    """Pillow's default font at ``px`` pixels (the bitmap font where it cannot scale)."""
    from PIL import ImageFont

    try:
        return ImageFont.load_default(size=px)
    except TypeError:  # Pillow without FreeType: the fixed bitmap font
        return ImageFont.load_default()


def _rgb(name: str) -> np.ndarray:
    """The RGB uint8 of :data:`~cdf_mj.viz.overlays.OVERLAY_COLORS` ``name``."""
    return (np.asarray(OVERLAY_COLORS[name][:3]) * 255).astype(np.uint8)


class Panel:
    """Probabilities, their history and a legend, drawn over the top-left of each frame.

    Args:
        replay: the episode; its ``posterior`` chooses the bars and curves.
        width, height: size of the frames drawn on [px]; the panel takes about 38 % of the
            width and 36 % of the height (at least 48 x 32 px, at most the frame).
        planner: the planner's name, in the head line.

    Needs Pillow (the ``viz`` extra); the background, legend and the curves over the
    whole episode are drawn once, each frame reveals them up to its time.
    """

    ALPHA = 0.82  # opacity of the panel over the scene

    def __init__(self, replay: Replay, width: int, height: int, planner: str) -> None:
        from PIL import Image, ImageDraw

        self._Image, self._ImageDraw = Image, ImageDraw
        self.replay = replay
        self.w = max(48, round(0.38 * width))
        self.h = max(32, round(0.36 * height))
        self.w, self.h = min(self.w, width), min(self.h, height)
        self.font = _font(max(7, round(self.h / 13)))
        # Rows: 0 head, 1 time and braking, 2-4 bars, 5-7 running plot, 8 legend.
        line = self.h / 9.0
        self.rows = [round(line * (i + 0.5)) for i in range(9)]  # text centres
        self.label_w = round(0.34 * self.w)
        self.bar_x0, self.bar_x1 = self.label_w, round(0.82 * self.w)
        self.bar_h = max(2, round(line * 0.6))
        self.plot = (round(0.04 * self.w), round(line * 5.1), round(0.96 * self.w),
                     round(line * 7.9))  # x0, y0, x1, y1
        self.keys = tuple(k for k in POSTERIOR_KEYS if replay.posterior is not None and k in replay.posterior)
        head = f"seed {replay.record.seed}  {planner}  label {replay.label or '-'}"
        self.base = self._background(head)
        self.curves = self._curves()

    def _text(self, img: np.ndarray, items: list[tuple[int, int, str, tuple[int, int, int]]]) -> np.ndarray:
        """``img`` with each ``(x, y, text, rgb)`` written, left end and vertical middle at x, y."""
        pil = self._Image.fromarray(img)
        draw = self._ImageDraw.Draw(pil)
        for x, y, text, color in items:
            draw.text((x, y), text, fill=color, font=self.font, anchor="lm")
        return np.array(pil)

    def _background(self, head: str) -> np.ndarray:
        """What every frame shares: head line, bar labels, legend and the plot's axes."""
        img = np.full((self.h, self.w, 3), 20, dtype=np.uint8)
        pad = max(2, self.w // 60)
        items = [(pad, self.rows[0], head, (235, 235, 235))]
        if self.replay.posterior is not None:
            for i, k in enumerate(self.keys):
                r, g, b = (int(v) for v in _rgb(k))
                items.append((pad, self.rows[2 + i], _LABELS[k], (r, g, b)))
        else:
            items.append((pad, self.rows[2], "no filter: planner without a posterior", (200, 200, 200)))
        # Legend of particle colours on the last row.
        x: float = pad
        step = (self.w - 2 * pad) / 4
        sw = max(2, self.bar_h)
        y = self.rows[8]
        for (intent, seen), rgba in PARTICLE_COLORS.items():
            img[y - sw // 2:y - sw // 2 + sw, int(x):int(x) + sw] = (np.asarray(rgba[:3]) * 255).astype(np.uint8)
            items.append((int(x) + sw + 2, y, intent[0].upper() + ("s" if seen else ""), (220, 220, 220)))
            x += step
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
            ys = self._y(post[k])
            col = _rgb(k)
            for i in range(len(tx)):
                xa, xb = tx[i], tx[i + 1] if i + 1 < len(tx) else tx[i]
                ya, yb = ys[i], ys[i + 1] if i + 1 < len(ys) else ys[i]
                n = max(abs(xb - xa), abs(yb - ya), 1) + 1
                xs = np.rint(np.linspace(xa, xb, n)).astype(int)
                yy = np.rint(np.linspace(ya, yb, n)).astype(int)
                img[yy, xs] = col
        return img

    def _x(self, t: np.ndarray | float) -> np.ndarray:
        """Plot column [px] of time(s) ``t`` [s]."""
        x0, _, x1, _ = self.plot
        end = max(self.replay.end_time, 1e-6)
        return np.rint(x0 + 1 + np.asarray(t) / end * (x1 - x0 - 1)).astype(int)

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
        items = [(pad, self.rows[1], f"t {t:5.2f} s", (235, 235, 235))]
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
                items.append((self.bar_x1 + pad, yc, f"{p:.2f}", (235, 235, 235)))
        img = self._text(img, items)
        region = frame[:self.h, :self.w]
        region[...] = (self.ALPHA * img + (1.0 - self.ALPHA) * region).astype(np.uint8)
        return frame

"""Animations of recorded runs (``cartpole analyze BAG --animate FILE``), no ROS.

The rig drawn from the front, at its true dimensions
(:class:`cartpole_sim.geometry.RigGeometry`: rail, both end stops, the x*
mark, cart, rod and tip mass, the tip at ``(x - l sin theta, l cos
theta)`` (4.5)), in the colour of the controller's mode (the live viewer's
colours), with a fading trace of the tip over the last
:data:`TRACE_SECONDS`, the time, the mode and the active controller, and
the catch: its time in the text and a cross where the tip was when it
happened. The thesis shows its simulations the same way (Figures
4.14/4.15).

Frames are sampled at ``fps`` frames a second of the animation, i.e. every
``speed / fps`` seconds of the run (``speed`` = 1: real speed), the states
interpolated linearly between the recorded samples. GIF through Pillow
(palette images drawn directly, so no colour quantisation per frame; each
frame stored as its difference to the previous one), MP4 through
``ffmpeg`` (H.264) when it is on the PATH.
"""
from __future__ import annotations

import math
import shutil
import subprocess
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Iterator, Sequence

import numpy as np

from cartpole_core.child_process import reap
from cartpole_sim.geometry import RigGeometry

from ..viewer.scene import MODE_COLOURS, NO_MODE_COLOUR, mode_key

TRACE_SECONDS = 1.5
"""Length of the tip's trace [s of the run]."""
TRACE_SHADES = 6
DEFAULT_FPS = 25.0
DEFAULT_WIDTH = 480
FORMATS = ('.gif', '.mp4')

_BACKGROUND, _RAIL, _STOP, _ROD, _TEXT, _REFERENCE, _CATCH, _PIVOT = range(8)
_MODE_INDEX = {mode: 8 + i for i, mode in enumerate(MODE_COLOURS)}
_NO_MODE = 8 + len(MODE_COLOURS)
_TRACE0 = _NO_MODE + 1


def _palette() -> list[int]:
    fixed = [(255, 255, 255), (150, 153, 158), (64, 64, 72), (120, 120, 120), (20, 20, 20),
             (120, 190, 130), (210, 30, 30), (40, 40, 40)]
    modes = [tuple(int(255 * c) for c in rgb) for rgb in MODE_COLOURS.values()]
    no_mode = [tuple(int(255 * c) for c in NO_MODE_COLOUR)]
    # The trace: from almost the background (oldest) to a saturated blue (newest).
    trace = [tuple(int(255 - (255 - end) * (i + 1) / TRACE_SHADES) for end in (30, 110, 220))
             for i in range(TRACE_SHADES)]
    flat = [c for rgb in fixed + modes + no_mode + trace for c in rgb]
    return flat + [0] * (768 - len(flat))


@dataclass
class AnimationSeries:
    """What an animation shows: the states over time, the modes, the catch.

    Attributes
    ----------
    t, x, theta
        Sample times [s] from the run's start, cart position [m], pendulum
        angle [rad] (0 upright, continuous).
    mode_t, modes
        Times [s] at which the controller's mode became ``modes[i]``
        (may be empty: no controller status recorded).
    catch_time
        First switch to the stabiliser [s], or None.
    x_ref
        x* [m].
    controllers
        Mode -> the plugin in charge (``{'swingup': 'pendulum_energy', ...}``).
    """

    t: np.ndarray
    x: np.ndarray
    theta: np.ndarray
    mode_t: np.ndarray
    modes: list[str]
    catch_time: float | None
    x_ref: float
    controllers: dict[str, str]

    def mode_at(self, t: float) -> str:
        k = int(np.searchsorted(self.mode_t, t, side='right')) - 1
        return self.modes[k] if k >= 0 else ''


def series_from_analysis(analysis) -> AnimationSeries:
    """The animation of a :class:`~cartpole_analysis.analysis.analyze.BagAnalysis` (states, catch, x*),
    with the controller's modes read from the bag's ``/cartpole/controller_status``."""
    from rosbags.highlevel import AnyReader
    from rosbags.typesys import Stores, get_typestore

    from ..bags.writer import bag_custom_data
    from .analyze import STATUS, root_topics

    series = analysis.series
    mode_t: list[float] = []
    modes: list[str] = []
    controllers: dict[str, str] = {}
    with AnyReader([Path(analysis.path)],
                   default_typestore=get_typestore(Stores.ROS2_JAZZY)) as reader:
        root = root_topics(reader, bag_custom_data(analysis.path))
        connections = [c for c in reader.connections if root[c.topic] == STATUS]
        for connection, _, raw in reader.messages(connections=connections):
            msg = reader.deserialize(raw, connection.msgtype)
            stamp = msg.header.stamp.sec * 1_000_000_000 + msg.header.stamp.nanosec
            for status in msg.status:
                values = {kv.key: kv.value for kv in status.values}
                mode = values.get('mode', status.message)
                for key in ('swingup', 'stabilizer'):
                    if values.get(key):
                        controllers[key] = values[key]
                if not modes or mode != modes[-1]:
                    mode_t.append((stamp - analysis.t0_ns) * 1e-9)
                    modes.append(mode)
    order = np.argsort(mode_t, kind='stable')
    return AnimationSeries(
        t=series.t, x=series.x, theta=series.theta, mode_t=np.asarray(mode_t)[order],
        modes=[modes[i] for i in order], catch_time=series.catch_time, x_ref=series.x_ref,
        controllers={'swingup': controllers.get('swingup', ''),
                     'stabilizing': controllers.get('stabilizer', '')})


@dataclass(frozen=True)
class Viewport:
    """World (rail frame x, z [m]) to pixel mapping of a frame of ``width`` x ``height`` px."""

    x_min: float
    z_max: float
    scale: float
    """Pixels per metre."""
    width: int
    height: int
    top: int
    """Height of the text strip above the drawing [px]."""

    @classmethod
    def for_rig(cls, geometry: RigGeometry, width: int = DEFAULT_WIDTH) -> 'Viewport':
        """The whole rig (stops included) and the pendulum's reach, with a margin."""
        margin = 0.03
        x_min = geometry.stop_centres_x[0] - 0.5 * geometry.stop_width - margin
        x_max = geometry.stop_centres_x[1] + 0.5 * geometry.stop_width + margin
        reach = geometry.pendulum_length + 0.5 * geometry.tip_height + margin
        width -= width % 2  # H.264 wants even sizes
        scale = width / (x_max - x_min)
        top = 34
        height = top + int(math.ceil(2 * reach * scale))
        return cls(x_min=x_min, z_max=reach, scale=scale, width=width,
                   height=height + height % 2, top=top)

    def to_pixel(self, x: float, z: float) -> tuple[float, float]:
        """Pixel (column, row) of the rail-frame point (x, z)."""
        return (x - self.x_min) * self.scale, self.top + (self.z_max - z) * self.scale


def frame_times(t_start: float, t_end: float, fps: float, speed: float) -> np.ndarray:
    """Run times [s] of the frames: every ``speed / fps`` s from ``t_start`` to ``t_end``."""
    if not (fps > 0 and speed > 0):
        raise ValueError(f'fps and speed must be > 0, got {fps}, {speed}')
    count = int(math.floor((t_end - t_start) * fps / speed + 1e-9)) + 1
    return t_start + np.arange(count) * (speed / fps)


def gif_durations(count: int, fps: float) -> list[int]:
    """Frame durations [ms] in GIF's 10 ms steps whose running sum follows ``k / fps``."""
    out, shown = [], 0
    for k in range(1, count + 1):
        target = int(round(k * 100.0 / fps)) * 10
        out.append(max(target - shown, 10))
        shown += out[-1]
    return out


class Renderer:
    """Draws frames of one series (see the module docstring)."""

    def __init__(self, series: AnimationSeries, geometry: RigGeometry,
                 width: int = DEFAULT_WIDTH) -> None:
        from PIL import Image, ImageDraw, ImageFont

        self.series = series
        self.geometry = geometry
        self.view = Viewport.for_rig(geometry, width)
        self._palette = _palette()
        self._font = ImageFont.load_default(size=14)
        self._draw_cls = ImageDraw.Draw
        self._base = Image.new('P', (self.view.width, self.view.height), _BACKGROUND)
        self._base.putpalette(self._palette)
        self._draw_rig(self._draw_cls(self._base))
        self.catch_tip = None
        if series.catch_time is not None:
            self.catch_tip = geometry.tip_position(*self.state_at(series.catch_time))

    def state_at(self, t: float) -> tuple[float, float]:
        s = self.series
        return float(np.interp(t, s.t, s.x)), float(np.interp(t, s.t, s.theta))

    def _px(self, x: float, z: float) -> tuple[int, int]:
        """Whole pixels (thick lines between fractional ends come out jagged)."""
        col, row = self.view.to_pixel(x, z)
        return round(col), round(row)

    def _rect(self, draw, x0: float, z0: float, x1: float, z1: float, fill: int) -> None:
        (a, b), (c, d) = self._px(x0, z1), self._px(x1, z0)
        draw.rectangle([a, b, c, d], fill=fill)

    def _draw_rig(self, draw) -> None:
        g = self.geometry
        left, right = g.rail_x_range
        zc = g.rail_centre_z
        self._rect(draw, left, zc - 0.5 * g.rail_height, right, zc + 0.5 * g.rail_height, _RAIL)
        for cx in g.stop_centres_x:
            self._rect(draw, cx - 0.5 * g.stop_width, zc - 0.5 * g.rail_height,
                       cx + 0.5 * g.stop_width, zc + 0.5 * g.rail_height + g.cart_height, _STOP)
        reach = g.pendulum_length + 0.5 * g.tip_height
        xr = self.series.x_ref
        draw.line([self._px(xr, -reach), self._px(xr, reach)], fill=_REFERENCE, width=1)
        px, py = self._px(xr, zc - 0.5 * g.rail_height)
        draw.text((px - 16, py + 2), 'x*', fill=_REFERENCE, font=self._font)

    def frame(self, t: float, trace: Sequence[tuple[int, int]]):
        """The frame at run time ``t``; ``trace`` are earlier tip pixels, oldest first."""
        g = self.geometry
        img = self._base.copy()
        draw = self._draw_cls(img)
        mode = self.series.mode_at(t)
        colour = _MODE_INDEX.get(mode_key(mode), _NO_MODE)
        n = len(trace)
        for i in range(1, n):
            shade = _TRACE0 + min(TRACE_SHADES - 1, i * TRACE_SHADES // max(n, 1))
            draw.line([trace[i - 1], trace[i]], fill=shade, width=2)
        caught = self.series.catch_time is not None and t >= self.series.catch_time
        if caught and self.catch_tip is not None:
            cx, cz = self._px(*self.catch_tip)
            draw.line([(cx - 5, cz - 5), (cx + 5, cz + 5)], fill=_CATCH, width=2)
            draw.line([(cx - 5, cz + 5), (cx + 5, cz - 5)], fill=_CATCH, width=2)
        x, theta = self.state_at(t)
        self._rect(draw, x - 0.5 * g.cart_width, -0.5 * g.cart_height, x + 0.5 * g.cart_width,
                   0.5 * g.cart_height, colour)
        pivot = self._px(x, 0.0)
        rod_end = self._px(*g.point_on_pendulum(x, theta, g.rod_length))
        rod_width = max(2, round(g.rod_diameter * self.view.scale))
        draw.line([pivot, rod_end], fill=_ROD, width=rod_width)
        tip_far = self._px(*g.point_on_pendulum(x, theta, g.pendulum_length + 0.5 * g.tip_height))
        draw.line([rod_end, tip_far], fill=colour,
                  width=max(3, round(g.tip_diameter * self.view.scale)))
        r = 3
        draw.ellipse([pivot[0] - r, pivot[1] - r, pivot[0] + r, pivot[1] + r], fill=_PIVOT)
        active = self.series.controllers.get(mode_key(mode), '')
        text = f't = {t:5.2f} s   {mode or "-"}' + (f' ({active})' if active else '')
        draw.text((8, 8), text, fill=_TEXT, font=self._font)
        if caught:
            label = f'catch at {self.series.catch_time:.2f} s'
            width = draw.textlength(label, font=self._font)
            draw.text((self.view.width - 8 - width, 8), label, fill=_CATCH, font=self._font)
        return img

    def frames(self, times: np.ndarray) -> Iterator:
        """Every frame at ``times``, with the tip's trace of the last :data:`TRACE_SECONDS`."""
        tips: list[tuple[float, tuple[int, int]]] = []
        for t in times:
            x, theta = self.state_at(t)
            tips.append((t, self._px(*self.geometry.tip_position(x, theta))))
            while tips and tips[0][0] < t - TRACE_SECONDS:
                tips.pop(0)
            yield self.frame(float(t), [p for _, p in tips])


@dataclass(frozen=True)
class AnimationInfo:
    """What :func:`write_animation` wrote."""

    path: Path
    frames: int
    duration_s: float
    """Playing time of the file [s]."""
    render_s: float
    """Wall time to draw and encode it [s]."""
    size_bytes: int
    width: int
    height: int


def write_animation(series: AnimationSeries, path: str | Path, geometry: RigGeometry, *,
                    fps: float = DEFAULT_FPS, speed: float = 1.0,
                    width: int = DEFAULT_WIDTH) -> AnimationInfo:
    """Render the run into ``path`` (``.gif``, or ``.mp4`` with ffmpeg); see the module docstring.

    Raises ValueError for an unknown extension, an empty series or a bad
    fps/speed/width, RuntimeError when an MP4 is asked for without ffmpeg.
    """
    path = Path(path)
    suffix = path.suffix.lower()
    if suffix not in FORMATS:
        raise ValueError(f'{path}: the animation must be one of {", ".join(FORMATS)}')
    if series.t.size < 2:
        raise ValueError('the run has fewer than two samples: nothing to animate')
    if not (isinstance(width, int) and 120 <= width <= 3840):
        raise ValueError(f'width must be an integer in [120, 3840] px, got {width!r}')
    ffmpeg = shutil.which('ffmpeg')
    if suffix == '.mp4' and ffmpeg is None:
        raise RuntimeError('an MP4 needs ffmpeg on the PATH (not found); write a .gif instead')
    started = time.perf_counter()
    renderer = Renderer(series, geometry, width)
    times = frame_times(float(series.t[0]), float(series.t[-1]), fps, speed)
    path.parent.mkdir(parents=True, exist_ok=True)
    if suffix == '.gif':
        durations = gif_durations(times.size, fps)
        frames = renderer.frames(times)
        first = next(frames)
        first.save(path, save_all=True, append_images=frames, duration=durations, loop=0,
                   optimize=True, disposal=1)
        duration = sum(durations) / 1000.0
    else:
        _write_mp4(ffmpeg, renderer, times, fps, path)
        duration = times.size / fps
    return AnimationInfo(path=path, frames=int(times.size), duration_s=duration,
                         render_s=time.perf_counter() - started,
                         size_bytes=path.stat().st_size, width=renderer.view.width,
                         height=renderer.view.height)


def _write_mp4(ffmpeg: str, renderer: Renderer, times: np.ndarray, fps: float,
               path: Path) -> None:
    view = renderer.view
    cmd = [ffmpeg, '-y', '-loglevel', 'error', '-f', 'rawvideo', '-pix_fmt', 'rgb24',
           '-s', f'{view.width}x{view.height}', '-r', f'{fps:g}', '-i', '-',
           '-c:v', 'libx264', '-pix_fmt', 'yuv420p', '-movflags', '+faststart', str(path)]
    proc = subprocess.Popen(cmd, stdin=subprocess.PIPE, stderr=subprocess.PIPE)
    try:
        for img in renderer.frames(times):
            proc.stdin.write(img.convert('RGB').tobytes())
        proc.stdin.close()
        err = proc.stderr.read().decode(errors='replace')
        if proc.wait() != 0:
            raise RuntimeError(f'ffmpeg failed: {err.strip()[-500:]}')
    finally:
        reap(proc, drain=False)

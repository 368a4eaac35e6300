"""Videos of a whole run: GIF (Pillow) or MP4 (an installed ffmpeg), and a strip of frames as PNG.

Frames come from the exact closed-form motion (the interval's polynomial, or its clipped or
matrix-exponential form, at ``s = t - t_k``) and are **uniform in time**: ``F = round(fps *
seconds)`` frames from ``t = 0`` to ``T_s``; the trails also pass through every sampling instant
(docs: video.md, "Video").
"""

from __future__ import annotations

import os
import shutil
import subprocess
from collections.abc import Iterable, Iterator, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from fxc_env.analysis.simulation import Trajectory
from fxc_env.core.dynamics import advance_clipped, state_inside
from fxc_env.core.validation import ArgumentError, integer, real
from fxc_env.engine import state_disagreement
from fxc_env.envs.rendering import FRAME_SIZE, SceneRenderer, data_limits, frame_size
from fxc_env.utils.cli_checks import output_directory

#: Frames per second of a video, and its length in seconds (``fxc simulate --video``).
VIDEO_FPS = 15
VIDEO_SECONDS = 8.0
#: The file types a video can be written as.
VIDEO_SUFFIXES = (".gif", ".mp4")
#: Frames side by side in a frame strip.
STRIP_FRAMES = 5
#: How long a GIF holds its last frame (ms), so that the final state can be read before it loops.
GIF_HOLD_MS = 1500
_FPS_RANGE = (1, 60)
_SECONDS_RANGE = (0.1, 600.0)
_MAX_FRAMES = 5000
_MP4_HINT = "pip install imageio-ffmpeg (or put an ffmpeg binary on PATH); .gif needs nothing more"


@dataclass(frozen=True)
class VideoOptions:
    """What to draw: ``fps`` frames per second for ``seconds`` seconds, frames ``size = (width, height)`` pixels."""

    fps: int = VIDEO_FPS
    seconds: float = VIDEO_SECONDS
    size: tuple[int, int] = FRAME_SIZE

    @property
    def n_frames(self) -> int:
        """``F = round(fps * seconds)``, at least 2 (the first frame at ``t = 0``, the last at ``T_s``)."""
        return max(2, round(self.fps * self.seconds))


def video_options(
    fps: Any = VIDEO_FPS,
    seconds: Any = VIDEO_SECONDS,
    size: Any = FRAME_SIZE,
    *,
    names: tuple[str, str, str] | None = None,
) -> VideoOptions:
    """Checked :class:`VideoOptions`; a bad value is refused naming it (``names``: the flags' names)."""
    fps_name, seconds_name, size_name = names or ("fps", "seconds", "size")
    fps = integer(fps_name, fps, *_FPS_RANGE)
    seconds = real(seconds_name, seconds, *_SECONDS_RANGE)
    options = VideoOptions(fps, seconds, frame_size(size_name, size))
    if options.n_frames > _MAX_FRAMES:
        raise ArgumentError(
            f"{fps_name}, {seconds_name}: {fps} frames/s for {seconds:g} s is {options.n_frames} frames; "
            f"at most {_MAX_FRAMES} are drawn"
        )
    return options


def mp4_encoder() -> str | None:
    """``"imageio-ffmpeg"`` or the path of an ``ffmpeg`` binary on PATH, whichever is installed first; else None."""
    try:
        import imageio_ffmpeg  # noqa: F401
    except ImportError:
        return shutil.which("ffmpeg")
    return "imageio-ffmpeg"


def check_video_path(name: str, path: Any, size: tuple[int, int] = FRAME_SIZE) -> Path:
    """``path`` as a video file to write: ``.gif``, or ``.mp4`` where an encoder is installed.

    Refused naming ``name``: another suffix, ``.mp4`` with no encoder (saying what to install:
    nothing is downloaded) or with an odd frame side (H.264 needs even ones), an existing
    directory, and a folder that cannot be created or written.
    """
    target = _file_path(name, path, VIDEO_SUFFIXES, ".gif or .mp4")
    if target.suffix.lower() == ".mp4":
        if mp4_encoder() is None:
            raise ArgumentError(f"{name}: writing .mp4 needs an encoder and none is installed: {_MP4_HINT}")
        if size[0] % 2 or size[1] % 2:
            raise ArgumentError(f"{name}: .mp4 (H.264) needs an even frame width and height, got {size[0]}x{size[1]}")
    output_directory(name, target.parent if str(target.parent) else ".")
    return target


def check_strip_path(name: str, path: Any) -> Path:
    """``path`` as a PNG file to write (refused naming ``name`` otherwise)."""
    target = _file_path(name, path, (".png",), ".png")
    output_directory(name, target.parent if str(target.parent) else ".")
    return target


def _file_path(name: str, path: Any, suffixes: Sequence[str], expected: str) -> Path:
    """``path`` once its suffix is one of ``suffixes`` (``expected`` says which) and no directory is there."""
    text = os.fspath(path)
    target = Path(text)
    if target.suffix.lower() not in suffixes:
        raise ArgumentError(f"{name}: expected a file name ending in {expected}, got {text!r}")
    if target.is_dir():
        raise ArgumentError(f"{name}: expected a file, got {text!r}, which is an existing directory")
    return target


# ---------------------------------------------------------------------------- exact states
def frame_times(settling_time: float, n_frames: int) -> np.ndarray:
    """``(F,)`` frame times uniform in ``[0, T_s]`` seconds, both ends included."""
    return np.linspace(0.0, float(settling_time), int(n_frames))


def interval_of(trajectory: Trajectory, times: np.ndarray) -> np.ndarray:
    """``(P,)`` index k of the interval ``[t_k, t_{k+1})`` each time lies in (``K - 1`` at ``T_s``)."""
    k_total = len(trajectory.times) - 1
    return np.clip(np.searchsorted(trajectory.times, times, side="right") - 1, 0, k_total - 1)


def states_at(trajectory: Trajectory, times: Any) -> np.ndarray:
    """The exact states at ``times`` (seconds in ``[0, T_s]``): ``(P, N, n, dim)`` in the engine's coordinates.

    The engine's coordinates are the formation error ``z_i - e^{A t} h_i`` when the run has
    formation offsets (:func:`absolute_positions` adds them back). Closed form in each
    interval (module docstring); the state at a sampling instant is the sampled one, bit for bit.
    """
    if trajectory.states is None:
        raise ArgumentError("trajectory: it has no states (made by an older simulate); run fxc_env.simulate again")
    times = np.asarray(times, dtype=float).reshape(-1)
    c = trajectory.config
    if not np.all(np.isfinite(times)) or np.any(times < 0) or np.any(times > c.settling_time):
        raise ArgumentError(f"times: every time must lie in [0, T_s] = [0, {c.settling_time!r}] s")
    k = interval_of(trajectory, times)
    intervals = np.diff(trajectory.times)
    s = np.minimum(times - trajectory.times[k], intervals[k])
    z = trajectory.states
    if c.model is None:  # the double integrator: eq. 11's affine input, cubic positions
        x, v = z[k, :, 0], z[k, :, 1]  # (P, N, dim)
        u0, u1 = trajectory.u_start[k], trajectory.u_end[k]
        T, offset = intervals[k][:, None, None], s[:, None, None]
        dx, dv, du = state_inside(x, v, u0, u1, T, offset)
        if trajectory.u_max is not None:  # the clipped line from u0 to u(s), integrated exactly over [0, s]
            reach = np.maximum(offset, np.finfo(float).tiny)
            dx, dv, *_ = advance_clipped(x, v, u0, du, reach, trajectory.u_max)
        out = np.stack([dx, dv], axis=2)
    else:
        maps = c.interval_maps
        out = np.empty((len(times), *z.shape[1:]))
        for interval in np.unique(k):
            rows = np.flatnonzero(k == interval)
            per_axis = np.swapaxes(z[interval], -1, -2)  # (N, dim, n)
            inside, _ = maps.state_inside(int(interval), per_axis, trajectory.plans[interval], s[rows])
            out[rows] = np.swapaxes(inside, -1, -2)
    # At a sampling instant, the sampled state itself (no rounding): t_k, and T_s at the end of the last interval.
    start, end = s == 0, times == trajectory.times[k + 1]
    out[start] = z[k[start]]
    out[end] = z[k[end] + 1]
    return out


def absolute_positions(trajectory: Trajectory, times: np.ndarray, states: np.ndarray) -> np.ndarray:
    """``(P, N, dim)`` absolute positions (m) from :func:`states_at`'s states (the offsets' motion added back)."""
    c = trajectory.config
    if c.formation is not None:
        states = states + c.free_motion(times)[:, None] @ c.formation
    return states[:, :, 0]


# ---------------------------------------------------------------------------- frames
def video_frames(
    trajectory: Trajectory, options: VideoOptions | None = None, *, title: str | None = None
) -> Iterator[np.ndarray]:
    """The video's ``options.n_frames`` frames, ``(H, W, 3)`` uint8 each, uniform in time (module docstring).

    The view limits are fixed for the whole video (every agent's whole path fits).
    """
    options = options or VideoOptions()
    c = trajectory.config
    times = frame_times(c.settling_time, options.n_frames)
    curve = np.union1d(times, trajectory.times)  # the trails: frame times and every sampling instant
    states = states_at(trajectory, curve)
    positions = absolute_positions(trajectory, curve, states)
    d0 = float(trajectory.disagreement[0])
    ratios = state_disagreement(states, c) / d0 if d0 > 0 else np.full(len(curve), np.nan)
    ends = np.searchsorted(curve, times)  # each frame time is in the curve
    intervals = interval_of(trajectory, times)
    graphs = trajectory.graphs
    period = trajectory.topology.period
    renderer = SceneRenderer(c, options.size, title=title)
    limits = data_limits(positions[:, : renderer.n_shown])
    for f, end in enumerate(ends):
        k = int(intervals[f])
        yield renderer.draw(
            curve[: end + 1],
            positions[: end + 1],
            ratio=float(ratios[end]),
            interval=len(trajectory.times) - 1 if f == len(ends) - 1 else k,
            graph=int(graphs[k]) if graphs is not None else k % period,
            topology=trajectory.topology,
            limits=limits,
        )


def strip_indices(n_frames: int, count: int = STRIP_FRAMES) -> np.ndarray:
    """``count`` frame indices spread evenly from the first frame to the last."""
    return np.unique(np.round(np.linspace(0, n_frames - 1, min(count, n_frames))).astype(int))


def frame_strip(frames: Iterable[np.ndarray]) -> np.ndarray:
    """Frames side by side, separated by a thin grey line: ``(H, n W + n - 1, 3)`` uint8."""
    pictures = list(frames)
    gap = np.full((pictures[0].shape[0], 1, 3), 160, dtype=np.uint8)
    joined = [pictures[0]]
    for picture in pictures[1:]:
        joined += [gap, picture]
    return np.concatenate(joined, axis=1)


def write_png(picture: np.ndarray, path: Path) -> Path:
    """``picture`` as a PNG with an adaptive 256-colour palette (small files for line drawings)."""
    from PIL import Image

    Image.fromarray(picture).quantize(colors=256, method=Image.Quantize.MEDIANCUT).save(path, optimize=True)
    return path


def write_gif(frames: Iterable[np.ndarray], path: Path, fps: int) -> int:
    """Write ``(H, W, 3)`` uint8 frames as a looping GIF (Pillow); returns the number of frames.

    Each frame lasts ``1000 / fps`` ms rounded to GIF's 10 ms, the last one :data:`GIF_HOLD_MS`.
    """
    from PIL import Image

    pictures = [Image.fromarray(frame).quantize(colors=256, method=Image.Quantize.MEDIANCUT) for frame in frames]
    if not pictures:
        raise ArgumentError("frames: a video needs at least one frame")
    step = max(10, round(100.0 / fps) * 10)
    durations = [step] * (len(pictures) - 1) + [max(step, GIF_HOLD_MS)]
    pictures[0].save(path, save_all=True, append_images=pictures[1:], duration=durations, loop=0, disposal=1)
    return len(pictures)


def write_mp4(frames: Iterable[np.ndarray], path: Path, fps: int, size: tuple[int, int]) -> int:
    """Write frames as H.264 MP4 with imageio-ffmpeg or an ``ffmpeg`` binary; returns the number of frames.

    Raises :class:`~fxc_env.core.validation.ArgumentError` naming ``path`` when neither is installed.
    """
    encoder = mp4_encoder()
    if encoder is None:
        raise ArgumentError(f"path: writing .mp4 needs an encoder and none is installed: {_MP4_HINT}")
    count = 0
    if encoder == "imageio-ffmpeg":
        import imageio_ffmpeg

        writer = imageio_ffmpeg.write_frames(str(path), size, fps=fps, macro_block_size=1, pix_fmt_out="yuv420p")
        writer.send(None)
        for frame in frames:
            writer.send(np.ascontiguousarray(frame))
            count += 1
        writer.close()
        return count
    width, height = size
    command = [
        encoder, "-y", "-loglevel", "error", "-f", "rawvideo", "-pix_fmt", "rgb24", "-s", f"{width}x{height}",
        "-r", str(fps), "-i", "-", "-an", "-vcodec", "libx264", "-pix_fmt", "yuv420p", str(path),
    ]  # fmt: skip
    with subprocess.Popen(command, stdin=subprocess.PIPE) as process:
        assert process.stdin is not None
        for frame in frames:
            process.stdin.write(np.ascontiguousarray(frame).tobytes())
            count += 1
        process.stdin.close()
        if process.wait() != 0:
            raise RuntimeError(f"ffmpeg failed writing {str(path)!r} (exit status {process.returncode})")
    return count


@dataclass(frozen=True)
class VideoReport:
    """What :func:`write_video` wrote: the files, the frame count and how fast frames were drawn (frames/s)."""

    video: Path | None
    strip: Path | None
    n_frames: int
    size: tuple[int, int]
    fps: int
    draw_rate: float


def write_video(
    trajectory: Trajectory,
    path: Any = None,
    options: VideoOptions | None = None,
    *,
    strip: Any = None,
    title: str | None = None,
) -> VideoReport:
    """Draw the run's video (:func:`video_frames`) into ``path`` (``.gif`` or ``.mp4``) and/or a PNG ``strip``.

    The strip puts :data:`STRIP_FRAMES` of the video's frames side by side, evenly spread from
    ``t = 0`` to ``T_s``. Both paths are checked before any frame is drawn.
    """
    import time

    options = options or VideoOptions()
    if path is None and strip is None:
        raise ArgumentError("path, strip: give a video path (.gif or .mp4), a strip path (.png), or both")
    video = None if path is None else check_video_path("path", path, options.size)
    strip_path = None if strip is None else check_strip_path("strip", strip)
    chosen = set(strip_indices(options.n_frames).tolist())
    kept: list[np.ndarray] = []
    drawing = 0.0

    def frames() -> Iterator[np.ndarray]:
        nonlocal drawing
        source = video_frames(trajectory, options, title=title)
        for index in range(options.n_frames):
            start = time.perf_counter()
            frame = next(source)
            drawing += time.perf_counter() - start
            if index in chosen:
                kept.append(frame)
            yield frame

    if video is None:
        count = sum(1 for _ in frames())
    elif video.suffix.lower() == ".gif":
        count = write_gif(frames(), video, options.fps)
    else:
        count = write_mp4(frames(), video, options.fps, options.size)
    if strip_path is not None:
        write_png(frame_strip(kept), strip_path)
    return VideoReport(video, strip_path, count, options.size, options.fps, count / drawing if drawing > 0 else 0.0)


# ---------------------------------------------------------------------------- command line
#: The flags that shape the frames, by destination (they apply only with ``--video`` or ``--frame-strip``).
_SHAPE_FLAGS = {"video_fps": "--video-fps", "video_seconds": "--video-seconds", "video_size": "--video-size"}


def add_video_arguments(parser: Any) -> None:
    """``fxc simulate``'s video flags (declared here once): ``--video``, ``--frame-strip``, fps, length, size."""
    width, height = FRAME_SIZE
    parser.add_argument("--video", default=None, help="write the run as a video: a .gif (Pillow) or .mp4 (ffmpeg)")
    parser.add_argument(
        "--frame-strip", default=None, help=f"write {STRIP_FRAMES} frames of the video side by side as a .png"
    )
    parser.add_argument(
        "--video-fps", type=int, default=None, help=f"frames per second of the video (default {VIDEO_FPS})"
    )
    parser.add_argument(
        "--video-seconds",
        type=float,
        default=None,
        help=f"length of the video in seconds, frames uniform in t from 0 to T_s (default {VIDEO_SECONDS:g})",
    )
    parser.add_argument(
        "--video-size", default=None, help=f"frame size WIDTHxHEIGHT in pixels (default {width}x{height})"
    )


def video_request(args: Any) -> tuple[Path | None, Path | None, VideoOptions] | None:
    """The checked video flags of ``args`` (None when neither ``--video`` nor ``--frame-strip`` is given).

    ``--video-fps``, ``--video-seconds`` and ``--video-size`` without either are refused by name
    (they would change nothing).
    """
    given = [flag for dest, flag in _SHAPE_FLAGS.items() if getattr(args, dest) is not None]
    width, height = FRAME_SIZE
    options = video_options(
        VIDEO_FPS if args.video_fps is None else args.video_fps,
        VIDEO_SECONDS if args.video_seconds is None else args.video_seconds,
        f"{width}x{height}" if args.video_size is None else args.video_size,
        names=("--video-fps", "--video-seconds", "--video-size"),
    )
    if args.video is None and args.frame_strip is None:
        if given:
            raise ArgumentError(f"{', '.join(given)}: applies only with --video or --frame-strip, and neither is given")
        return None
    video = None if args.video is None else check_video_path("--video", args.video, options.size)
    strip = None if args.frame_strip is None else check_strip_path("--frame-strip", args.frame_strip)
    return video, strip, options

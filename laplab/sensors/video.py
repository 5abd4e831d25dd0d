"""Episode videos: the top-down view and the car's camera side by side, with the step's numbers.

MP4 (H.264) through ``imageio-ffmpeg`` when it is installed, else an animated GIF through PIL.
Frames are composed and written one at a time, so long episodes stream to MP4 without holding
every frame in memory (GIF needs them all, as palette images).
"""

from __future__ import annotations

import warnings
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from PIL import Image, ImageDraw, ImageFont


@dataclass(frozen=True)
class VideoParams:
    """``fps`` frames per second (DeepRacer decides at 15 Hz); ``camera_scale`` integer upscaling of
    camera frames (None: the largest that fits the top-down view's height); text in a bar below."""

    fps: float = 15.0
    camera_scale: int | None = None
    font_size: int = 16
    bar_color: tuple[int, int, int] = (16, 17, 22)
    text_color: tuple[int, int, int] = (235, 235, 235)
    gif_colors: int = 128

    def __post_init__(self) -> None:
        if not self.fps > 0:
            raise ValueError(f"VideoParams.fps must be positive, got {self.fps!r}")
        if self.camera_scale is not None and (int(self.camera_scale) != self.camera_scale or self.camera_scale < 1):
            raise ValueError(f"VideoParams.camera_scale must be a positive integer or None, got {self.camera_scale!r}")


DEFAULT_VIDEO = VideoParams()

# key -> (label, format) for the numbers DeepRacer users read; other keys print as "key value".
_OVERLAY_FORMATS = {
    "speed": ("speed", "{:.2f} m/s"),
    "steering": ("steering", "{:+.1f}\N{DEGREE SIGN}"),
    "steering_angle": ("steering", "{:+.1f}\N{DEGREE SIGN}"),
    "progress": ("progress", "{:.1f} %"),
    "reward": ("reward", "{:.3f}"),
}


def _font(size: int) -> ImageFont.ImageFont:
    try:
        return ImageFont.load_default(size=size)
    except (TypeError, OSError):  # Pillow without FreeType: fixed bitmap font
        return ImageFont.load_default()


def camera_to_rgb(frame: np.ndarray) -> np.ndarray:
    """A camera frame (H, W) or (H, W, 1) gray, (H, W, 2) stereo or (H, W, 3) RGB -> (H, W', 3) uint8.

    Stereo frames show left and right images side by side (W' = 2 W).
    """
    frame = np.asarray(frame)
    if frame.dtype != np.uint8:
        raise ValueError(f"camera frames must be uint8, got {frame.dtype}")
    if frame.ndim == 3 and frame.shape[2] == 1:
        frame = frame[:, :, 0]
    if frame.ndim == 2:
        return np.repeat(frame[:, :, None], 3, axis=2)
    if frame.ndim == 3 and frame.shape[2] == 2:
        return np.repeat(np.hstack([frame[:, :, 0], frame[:, :, 1]])[:, :, None], 3, axis=2)
    if frame.ndim == 3 and frame.shape[2] == 3:
        return frame
    raise ValueError(f"camera frames must be (H, W) gray, (H, W, 1), (H, W, 2) stereo or (H, W, 3) RGB; "
                     f"got shape {frame.shape}")


def format_overlay(step: int | None, values: Mapping[str, object] | None) -> str:
    """One line of text: ``step 12   speed 1.80 m/s   steering -12.0°   progress 34.5 %   reward 0.870``."""
    parts = [] if step is None else [f"step {step}"]
    for key, value in (values or {}).items():
        label, fmt = _OVERLAY_FORMATS.get(key, (key, None))
        if isinstance(value, (bool, np.bool_, str)) or fmt is None:
            text = f"{float(value):.4g}" if isinstance(value, (float, np.floating)) else str(value)
        else:
            text = fmt.format(float(value))
        parts.append(f"{label} {text}")
    return "   ".join(parts)


def compose_frame(topdown: np.ndarray, camera: np.ndarray | None = None, text: str = "",
                  params: VideoParams = DEFAULT_VIDEO) -> np.ndarray:
    """One video frame: top-down (H, W, 3) | upscaled camera, with ``text`` in a bar below -> uint8 RGB."""
    topdown = np.asarray(topdown)
    if topdown.dtype != np.uint8 or topdown.ndim != 3 or topdown.shape[2] != 3:
        raise ValueError(f"top-down frames must be (H, W, 3) uint8, got {topdown.shape} {topdown.dtype}")
    height = topdown.shape[0]
    panels = [topdown]
    if camera is not None:
        cam = camera_to_rgb(camera)
        scale = params.camera_scale or max(1, height // cam.shape[0])
        cam = np.repeat(np.repeat(cam, scale, axis=0), scale, axis=1)
        height = max(height, cam.shape[0])
        panels.append(cam)
    font = _font(params.font_size)
    bar = params.font_size + 12
    width = sum(p.shape[1] for p in panels)
    canvas = np.empty((height + bar, width, 3), dtype=np.uint8)
    canvas[:] = params.bar_color
    x = 0
    for panel in panels:
        top = (height - panel.shape[0]) // 2
        canvas[top:top + panel.shape[0], x:x + panel.shape[1]] = panel
        x += panel.shape[1]
    if text:
        image = Image.fromarray(canvas)
        ImageDraw.Draw(image).text((8, height + 6), text, fill=params.text_color, font=font)
        canvas = np.asarray(image)
    return canvas


def _overlay_rows(overlays, count: int) -> list[Mapping[str, object]]:
    """Per-frame dicts from None, a list of T dicts, or a dict of T-long columns."""
    if overlays is None:
        return [{}] * count
    if isinstance(overlays, Mapping):
        columns = {key: list(values) for key, values in overlays.items()}
        bad = {key: len(v) for key, v in columns.items() if len(v) != count}
        if bad:
            raise ValueError(f"write_episode_video: overlay columns must have one value per frame ({count}); "
                             f"got lengths {bad}")
        return [{key: values[t] for key, values in columns.items()} for t in range(count)]
    rows = list(overlays)
    if len(rows) != count:
        raise ValueError(f"write_episode_video: {len(rows)} overlay rows for {count} frames")
    return rows


def _pad_to_block(frame: np.ndarray, block: int = 16) -> np.ndarray:
    """Pad with black to a multiple of ``block`` pixels, as H.264 in yuv420p needs (no rescaling)."""
    pad_h, pad_w = -frame.shape[0] % block, -frame.shape[1] % block
    return np.pad(frame, ((0, pad_h), (0, pad_w), (0, 0))) if pad_h or pad_w else frame


def write_episode_video(path: str | Path, topdown_frames: Sequence[np.ndarray],
                        camera_frames: Sequence[np.ndarray] | np.ndarray | None = None,
                        overlays: Mapping[str, Sequence] | Sequence[Mapping] | None = None,
                        params: VideoParams = DEFAULT_VIDEO) -> Path:
    """Write T frames to ``path`` (.mp4 or .gif) and return the path written.

    topdown_frames: T x (H, W, 3) uint8 (e.g. from :func:`laplab.sensors.render.draw_topdown`).
    camera_frames: T x camera frame, or an array (T, H, W) gray / (T, H, W, C) with C in 1, 2, 3.
    overlays: per-step numbers: {"speed": [...], "steering": [...], "progress": [...], "reward": [...]}
    or a list of T such dicts. A ``.mp4`` path becomes ``.gif`` (with a warning) when imageio-ffmpeg is
    not installed.
    """
    path = Path(path)
    if path.suffix.lower() not in (".mp4", ".gif"):
        raise ValueError(f"write_episode_video: {path}: the file name must end in .mp4 or .gif")
    count = len(topdown_frames)
    if count == 0:
        raise ValueError("write_episode_video: no frames to write")
    if camera_frames is not None and len(camera_frames) != count:
        raise ValueError(f"write_episode_video: {len(camera_frames)} camera frames for {count} top-down frames")
    rows = _overlay_rows(overlays, count)
    frames = (compose_frame(topdown_frames[t], None if camera_frames is None else camera_frames[t],
                            format_overlay(t + 1, rows[t]), params) for t in range(count))
    if path.suffix.lower() == ".mp4":
        try:
            import imageio_ffmpeg
        except ImportError:
            path = path.with_suffix(".gif")
            warnings.warn(f"imageio-ffmpeg is not installed (pip install imageio-ffmpeg); writing {path} instead",
                          stacklevel=2)
        else:
            _write_mp4(imageio_ffmpeg, path, frames, params)
            return path
    _write_gif(path, frames, params)
    return path


def _write_mp4(imageio_ffmpeg, path: Path, frames, params: VideoParams) -> None:
    first = _pad_to_block(next(frames))
    path.parent.mkdir(parents=True, exist_ok=True)
    writer = imageio_ffmpeg.write_frames(str(path), (first.shape[1], first.shape[0]), fps=params.fps,
                                         codec="libx264", pix_fmt_in="rgb24", pix_fmt_out="yuv420p",
                                         macro_block_size=16, quality=7, ffmpeg_log_level="error")
    writer.send(None)  # start the generator
    try:
        writer.send(np.ascontiguousarray(first))
        for frame in frames:
            frame = _pad_to_block(frame)
            if frame.shape != first.shape:
                raise ValueError(f"write_episode_video: frame size changed from {first.shape} to {frame.shape}; "
                                 "all top-down and camera frames of an episode must have one size")
            writer.send(np.ascontiguousarray(frame))
    finally:
        writer.close()


def _write_gif(path: Path, frames, params: VideoParams) -> None:
    images = [Image.fromarray(f).quantize(params.gif_colors, method=Image.Quantize.FASTOCTREE) for f in frames]
    sizes = {im.size for im in images}
    if len(sizes) > 1:
        raise ValueError(f"write_episode_video: frames of several sizes {sorted(sizes)}; all top-down and camera "
                         "frames of an episode must have one size")
    path.parent.mkdir(parents=True, exist_ok=True)
    images[0].save(path, save_all=True, append_images=images[1:], duration=round(1000 / params.fps), loop=0,
                   optimize=False, disposal=1)

"""Offscreen flythroughs: render a camera path to PNG frames, an animated GIF or a movie (MP4, WebM,
MKV, MOV through imageio's ffmpeg), with a per-frame CSV.

This is ``clipvol view --offscreen``. By default every frame is rendered *as it comes*
(``wait=False``): what is resident is drawn, coarse levels stand in for bricks still loading, and
the CSV shows the cost of each frame and how the data streams in (bytes loaded and uploaded,
bricks drawn per level, resident memory). ``converged=True`` waits each frame until the wanted
bricks are all drawn at their own level, which gives reproducible frames.

Ctrl-C stops cleanly: the CSV is flushed and closed, the frames written so far stay (a GIF is
written with the frames rendered so far), the loader threads are joined, then the
``KeyboardInterrupt`` propagates (the CLI exits with 130).

A movie is encoded as the frames come (never held in memory) into a hidden ``.NAME.partial.EXT``
beside the output and renamed when it is closed: an error leaves no file that looks complete
(Ctrl-C keeps the frames so far, like the GIF). Frames are composited over black and padded to
even sizes (H.264 with 4:2:0 chroma needs them). A store built from a patient-frame file
(NIfTI, DICOM) can be labelled: ``orientation`` writes the anatomical direction of each image
edge (R/L, A/P, S/I) on every frame.
"""

from __future__ import annotations

import csv
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable

import numpy as np

from .. import interrupts
from ..errors import ParameterError
from ..scene.params import RenderParams
from ..scene.paths import make_path
from .session import RenderSession

__all__ = ["PathResult", "render_path", "frame_row", "save_gif", "save_png", "MovieWriter", "MOVIE_SUFFIXES",
           "CSV_BASE_COLUMNS"]

#: output suffixes written as movies through imageio-ffmpeg
MOVIE_SUFFIXES = (".mp4", ".webm", ".mkv", ".mov", ".avi")

CSV_BASE_COLUMNS = (
    "frame", "frame_s", "elapsed_s", "converged", "bricks_drawn", "texels_drawn", "bytes_loaded",
    "bytes_loaded_total", "bytes_uploaded", "resident_mb", "queued",
)


@dataclass
class PathResult:
    """What :func:`render_path` wrote."""

    frames: int = 0
    files: list[Path] = field(default_factory=list)
    csv: Path | None = None
    gif: Path | None = None
    movie: Path | None = None
    rows: list[dict] = field(default_factory=list)


def _over_black(img: np.ndarray) -> np.ndarray:
    """RGB of an RGBA frame over black (the renderer's colours are premultiplied-equivalent here)."""
    a = img[..., 3:4].astype(np.float32) / 255.0
    return np.clip(img[..., :3].astype(np.float32) * a + 0.5, 0, 255).astype(np.uint8)


class MovieWriter:
    """Frames to a movie file through imageio + imageio-ffmpeg, encoded as they come.

    Parameters
    ----------
    path : Path
        The movie (``.mp4``, ``.webm``, ``.mkv``, ``.mov``, ``.avi``).
    fps : float
        Frame rate.
    quality : float
        imageio's 0 (smallest) .. 10 (best) scale.
    """

    def __init__(self, path: Path, fps: float = 24.0, quality: float = 8.0) -> None:
        try:
            import imageio.v2 as iio
            import imageio_ffmpeg  # noqa: F401  (the ffmpeg binary ships in this wheel)
        except ImportError:
            from ..errors import MissingExtraError

            raise MissingExtraError(f"{path}: writing a movie needs imageio and imageio-ffmpeg: pip install 'clipvol[movie]'") from None
        if not (0 < float(fps) <= 240):
            raise ParameterError(f"fps: expected 0 < fps <= 240, got {fps!r}")
        if not (0 <= float(quality) <= 10):
            raise ParameterError(f"quality: expected 0..10, got {quality!r}")
        self.path = Path(path)
        self.partial = self.path.with_name(f".{self.path.stem}.partial{self.path.suffix}")
        self.frames = 0
        self._writer = iio.get_writer(self.partial, fps=float(fps), quality=float(quality), macro_block_size=1,
                                      ffmpeg_log_level="error")

    def append(self, img: np.ndarray) -> None:
        """Add an RGBA or RGB frame (composited over black, padded to even width and height)."""
        rgb = _over_black(img) if img.shape[-1] == 4 else np.asarray(img, dtype=np.uint8)
        h, w = rgb.shape[:2]
        if h % 2 or w % 2:
            rgb = np.pad(rgb, ((0, h % 2), (0, w % 2), (0, 0)))
        self._writer.append_data(rgb)
        self.frames += 1

    def close(self, keep: bool = True) -> None:
        """Finish the file and give it its name (``keep``), or delete it."""
        self._writer.close()
        if keep and self.frames:
            self.partial.replace(self.path)
        else:
            self.partial.unlink(missing_ok=True)


def frame_row(session: RenderSession, frame: int, frame_s: float, elapsed_s: float, bytes_before: int) -> dict:
    """One CSV row of statistics for the frame just rendered by ``session``."""
    fs = session.frame_stats
    ts = session.texture_stats
    row = {
        "frame": frame,
        "frame_s": round(frame_s, 6),
        "elapsed_s": round(elapsed_s, 6),
        "converged": int(fs.converged),
        "bricks_drawn": fs.bricks_distinct,  # distinct bricks, as in the report's CSV
        "texels_drawn": fs.texels_drawn,
        "bytes_loaded": ts.bytes_loaded - int(bytes_before),
        "bytes_loaded_total": ts.bytes_loaded,
        "bytes_uploaded": fs.bytes_uploaded,
        "resident_mb": round(ts.resident_bytes / 1e6, 3),
        "queued": ts.queued,
    }
    distinct = {(it.level, tuple(it.index)) for it in session.last_items()}
    for L in range(session.pyramid.num_levels):  # distinct bricks per level: they add up to bricks_drawn
        row[f"bricks_L{L}"] = sum(1 for lv, _ in distinct if lv == L)
    return row


def save_png(img: np.ndarray, path: Path) -> None:
    """Write straight RGBA ``img`` as a PNG at ``path``, all or nothing: into ``<path>.part`` first,
    renamed when complete (and the part removed if writing stops), so a frame file that exists is
    whole - also after a Ctrl-C in the middle of writing it."""
    from PIL import Image

    path = Path(path)
    tmp = path.with_name(path.name + ".part")
    try:
        Image.fromarray(img, "RGBA").save(tmp, format="PNG")
        tmp.replace(path)
    finally:
        tmp.unlink(missing_ok=True)


def save_gif(frames: list[np.ndarray], path: Path, fps: float = 12.0, background=(0, 0, 0)) -> None:
    """Write RGBA frames as a looping animated GIF (composited over ``background``, adaptive palette)."""
    from PIL import Image

    if not frames:
        return
    imgs = []
    bg = np.array(background, dtype=np.float32)
    for f in frames:
        a = f[..., 3:4].astype(np.float32) / 255.0
        rgb = f[..., :3].astype(np.float32) * a + bg * (1 - a)  # straight alpha over the background
        imgs.append(Image.fromarray(np.clip(rgb + 0.5, 0, 255).astype(np.uint8), "RGB").quantize(colors=255, method=Image.Quantize.MEDIANCUT))
    duration = int(round(1000.0 / max(float(fps), 0.1)))
    imgs[0].save(path, save_all=True, append_images=imgs[1:], duration=duration, loop=0, optimize=False)


def render_path(
    source,
    out,
    *,
    path: str = "orbit",
    frames: int = 36,
    size=(256, 256),
    converged: bool = False,
    timeout: float | None = 60.0,
    memory_budget="256MB",
    texture_budget="256MB",
    threads: int | None = None,
    params: RenderParams | None = None,
    tf="viridis",
    outlines: bool = False,
    fps: float = 12.0,
    ctx=None,
    session: RenderSession | None = None,
    progress: Callable[[dict], None] | None = None,
    path_kwargs: dict | None = None,
    quality: float = 8.0,
    orientation=None,
    on_failed: Callable | None = None,
) -> PathResult:
    """Render ``frames`` views along camera path ``path`` of ``source`` and write them to ``out``.

    Parameters
    ----------
    source : loader, path or URL
        The data (see :func:`clipvol.paging.open.open_store`).
    out : str or Path
        A directory (PNG frames ``frame_0000.png``... and ``frames.csv``), a ``.gif`` file or a
        movie (``.mp4``, ``.webm``, ``.mkv``, ``.mov``, ``.avi``), with ``<name>.<suffix>.csv`` beside it
        (``anim.gif.csv``, ``anim.mp4.csv``: a GIF and a movie of one run do not overwrite each other's).
    path : {'orbit', 'turntable', 'fly', 'zoom'}
        The camera path (:mod:`clipvol.scene.paths`).
    frames : int
        Number of frames.
    size : (int, int)
        Image ``(width, height)``.
    converged : bool
        Wait for every frame's wanted bricks (``wait=True``) instead of drawing what is resident.
    timeout : float, optional
        Seconds to wait per frame when ``converged``.
    memory_budget, texture_budget, threads
        Clip-texture and GPU cache budgets, loader threads.
    params : RenderParams, optional
        Selection policy, LOD threshold, MIP/composite, step (``texture_budget`` above wins);
        default ``RenderParams(jitter=True)`` (no wood-grain rings).
    tf : str or TransferFunction
        The transfer function.
    outlines : bool
        Draw each frame's bricks outlined in their level's colour.
    fps : float
        GIF or movie frame rate.
    ctx : moderngl.Context, optional
        A GL context to use; default a standalone EGL one (created and released here).
    session : RenderSession, optional
        An open session to render with instead of opening ``source`` (it is not closed here).
    progress : callable, optional
        Called with each frame's CSV row.
    path_kwargs : dict, optional
        Extra keyword arguments for the path function.
    quality : float
        Movie quality on imageio's 0..10 scale.
    orientation : WorldFrame, optional
        Write each frame's edge labels (R/L, A/P, S/I, or +X/-X... for a non-anatomical frame).
        Frames of a store whose array axes mirror the patient are flipped left-right either way
        (:func:`clipvol.app.annotate.present`), so they show the patient as ``clipvol render`` does.
    on_failed : callable, optional
        Called as ``on_failed(k, camera, image, failed_bricks)`` for a frame whose wanted bricks
        include failed ones (:attr:`~clipvol.render.frame_stats.FrameStats.failed_bricks`); returns the
        image to write (e.g. hatched) or raises to stop the path there (the frames before stay).

    Returns
    -------
    PathResult
    """

    out = Path(out)
    gif = out.suffix.lower() == ".gif"
    movie = out.suffix.lower() in MOVIE_SUFFIXES
    if gif or movie:
        out.parent.mkdir(parents=True, exist_ok=True)
        csv_path = out.with_name(out.name + ".csv")  # anim.gif.csv: a GIF and a movie of one name keep their own
    else:
        if out.exists() and not out.is_dir():
            raise ParameterError(f"out: expected a directory or a .gif file, got the existing file {out}")
        out.mkdir(parents=True, exist_ok=True)
        csv_path = out / "frames.csv"
    own_ctx = own_session = False
    result = PathResult(csv=csv_path, gif=out if gif else None, movie=out if movie else None)
    gif_frames: list[np.ndarray] = []
    fh = None
    movie_writer: MovieWriter | None = None
    keep_movie = False
    try:
        if movie:
            movie_writer = MovieWriter(out, fps=fps, quality=quality)
        if session is None:
            if ctx is None:
                from ..render.context import create_context

                ctx = create_context()
                own_ctx = True
            session = RenderSession(source, ctx, memory_budget=memory_budget, texture_budget=texture_budget,
                                    threads=threads, tf=tf,
                                    params=params if params is not None else RenderParams(jitter=True))
            own_session = True
        cams = make_path(path, session.pyramid, frames, size=size, **(path_kwargs or {}))
        fh = open(csv_path, "w", newline="")
        columns = list(CSV_BASE_COLUMNS) + [f"bricks_L{L}" for L in range(session.pyramid.num_levels)]
        writer = csv.DictWriter(fh, fieldnames=columns)
        writer.writeheader()
        t_start = time.perf_counter()
        before = 0  # bytes_loaded counts what the loader threads read since the previous row
        for k, (cam, coi) in enumerate(cams):
            interrupts.check()  # a Ctrl-C swallowed inside the previous frame stops the path here
            img, dt = session.timed_render(cam, coi, wait=converged, timeout=timeout if converged else None)
            st = session.frame_stats
            if on_failed is not None and st is not None and st.failed_bricks:
                img = on_failed(k, cam, img, st.failed_bricks)
            if outlines:
                from .overlay import draw_outlines

                img = draw_outlines(img, cam, session.last_items())
            from .annotate import present

            img = present(img, cam, getattr(session.loader, "frame", None), labels=False)  # a mirrored store: flipped
            if orientation is not None:
                from ..scene.orientation import view_labels
                from ..scene.views import screen_axes
                from .annotate import label_edges

                right, up = screen_axes(cam, getattr(session.loader, "frame", None))
                img = label_edges(img, view_labels(orientation.affine, right, up, orientation.frame))
            row = frame_row(session, k, dt, time.perf_counter() - t_start, before)
            before = row["bytes_loaded_total"]
            if gif:
                gif_frames.append(img)
            elif movie_writer is not None:
                movie_writer.append(img)
            else:
                f = out / f"frame_{k:04d}.png"
                save_png(img, f)
                result.files.append(f)
            writer.writerow(row)  # after its frame: a row names a frame that is there
            result.rows.append(row)
            result.frames += 1
            if progress is not None:
                progress(row)
        keep_movie = True
    except KeyboardInterrupt:
        keep_movie = True  # like the GIF: the frames rendered so far stay
        raise
    finally:
        if fh is not None:
            fh.close()
        if movie_writer is not None:
            movie_writer.close(keep=keep_movie)
            if keep_movie and movie_writer.frames:
                result.files.append(out)
        if gif and gif_frames:
            save_gif(gif_frames, out, fps=fps)
            result.files.append(out)
        if own_session and session is not None:
            session.close()
        if own_ctx and ctx is not None:
            ctx.release()
    return result

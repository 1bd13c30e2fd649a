"""Masks shipped with a data set (``external``): label images, per-object folders or an .npz
(layouts in :mod:`geocon_core.masks`)."""

from __future__ import annotations

import re
import zipfile
from pathlib import Path

import cv2
import numpy as np

from ..files import FRAME_IMAGE, MASKS_ARCHIVE, NPZ_ERRORS, regular_file
from ..media import ClipInfo, Frame, imread_any, native_path
from .base import MAX_ID, Coverage, labels_to_canvas

__all__ = ["ExternalMasks", "check_masks_path"]

_DIGITS = re.compile(r"(\d+)$")
_OBJECT_DIR = re.compile(r"^(?:obj_)?(\d+)$", re.IGNORECASE)
_LAYOUTS = (
    "expected a folder of label PNGs (00000.png, ...), a folder of per-object folders "
    "(<id>/00000.png or obj_<id>/00000.png) or an .npz file with an array 'labels'"
)


def _frame_files(folder: Path, num_frames: int, what: str) -> list[Path]:
    """The PNGs of ``folder`` in frame order, checked to be numbered consecutively from 0 or 1
    and to be exactly ``num_frames``."""
    files = [p for p in folder.iterdir() if p.suffix.lower() == ".png"]
    for p in files:  # a FIFO, a device or a folder named as a mask: refused, never skipped (nor opened)
        regular_file(p, FRAME_IMAGE)
    numbered: dict[int, Path] = {}
    for p in files:
        m = _DIGITS.search(p.stem)
        if m is None:
            raise ValueError(f"{p}: a mask file name must end in its frame number")
        k = int(m.group(1))
        if k in numbered:
            raise ValueError(f"{folder}: two mask files for frame {k} ({numbered[k].name}, {p.name})")
        numbered[k] = p
    if not numbered:
        raise ValueError(f"{folder}: holds no PNG {what}")
    idx = sorted(numbered)
    start = idx[0]
    if start not in (0, 1):
        raise ValueError(f"{folder}: mask frames must be numbered from 0 (or 1), the first is {numbered[start].name}")
    missing = sorted(set(range(start, start + max(num_frames, len(idx)))) - set(idx))
    if missing and missing[0] < idx[-1]:
        raise ValueError(f"{folder}: mask file of frame {missing[0] - start} is missing (found {len(idx)} {what})")
    if len(idx) != num_frames:
        raise ValueError(f"{folder}: has {len(idx)} {what} but the clip has {num_frames} frames")
    return [numbered[k] for k in idx]


_PNG_SIGNATURE = b"\x89PNG\r\n\x1a\n"
_PNG_PALETTE = 3
"""PNG colour type of an indexed (palette) image: the DAVIS / YouTube-VOS mask layout, whose
pixel values are the object ids and whose palette only colours them."""


def _is_palette_png(path: Path) -> bool:
    """Whether ``path`` is an indexed PNG (IHDR colour type 3)."""
    try:
        with open(path, "rb") as f:
            head = f.read(26)
    except OSError:
        return False
    return len(head) == 26 and head[:8] == _PNG_SIGNATURE and head[12:16] == b"IHDR" and head[25] == _PNG_PALETTE


def _read_palette_png(path: Path) -> np.ndarray | None:
    """The palette indices (h, w) uint8 of an indexed PNG (OpenCV would expand them to colours)."""
    import av

    try:
        with native_path(str(path)) as safe, av.open(safe) as container:
            for frame in container.decode(video=0):
                if frame.format.name == "pal8":
                    indices, _palette = frame.to_ndarray()
                    return np.ascontiguousarray(indices)
                return None
    except (av.FFmpegError, OSError, ValueError):
        return None
    return None


def _read_png(path: Path) -> np.ndarray:
    regular_file(path, FRAME_IMAGE)  # a FIFO or a device is never opened, a file past the bound never read
    if _is_palette_png(path):
        ids = _read_palette_png(path)
        if ids is None:
            raise ValueError(f"{path}: cannot be read as an indexed (palette) PNG")
        return ids
    img = imread_any(path, cv2.IMREAD_UNCHANGED)
    if img is None:
        raise ValueError(f"{path}: cannot be read as an image")
    if img.ndim == 3:
        if img.shape[2] == 1 or all(np.array_equal(img[..., 0], img[..., c]) for c in range(1, min(3, img.shape[2]))):
            img = img[..., 0]
        else:
            raise ValueError(
                f"{path}: is a colour image; label masks must be single-channel 8- or 16-bit PNGs "
                "or indexed (palette) PNGs whose indices are the object ids"
            )
    if img.dtype not in (np.uint8, np.uint16):
        raise ValueError(f"{path}: has {img.dtype} pixels; label masks must be 8- or 16-bit")
    return img


def _check_ids(lab: np.ndarray, where: str) -> np.ndarray:
    if lab.size and int(lab.max()) > MAX_ID:
        raise ValueError(f"{where}: object id {int(lab.max())} is above {MAX_ID}")
    if lab.size and lab.dtype.kind == "i" and int(lab.min()) < 0:
        raise ValueError(f"{where}: negative label {int(lab.min())}")
    return lab.astype(np.uint8, copy=False)


def _check_size(img: np.ndarray, info: ClipInfo, where: str) -> None:
    w, h = info.source_size
    if img.shape[:2] != (h, w):
        raise ValueError(f"{where}: mask is {img.shape[1]}x{img.shape[0]} but the clip's frames are {w}x{h}")


def _object_dirs(p: Path) -> list[tuple[int, Path]]:
    """The per-object folders of ``p`` by ascending id (``[]`` when it has none)."""
    dirs = []
    for c in p.iterdir():
        m = _OBJECT_DIR.match(c.name)
        if c.is_dir() and m:
            oid = int(m.group(1))
            if not 1 <= oid <= MAX_ID:
                raise ValueError(f"{c}: object id {oid} is outside 1..{MAX_ID}")
            dirs.append((oid, c))
    ids = [oid for oid, _ in dirs]
    if len(set(ids)) != len(ids):
        raise ValueError(f"{p}: two folders name the same object id")
    return sorted(dirs)


def _check_npz_header(p: Path) -> None:
    """The ``labels`` array of an .npz is there and is a plain integer array (its header only)."""
    if not zipfile.is_zipfile(p):
        raise ValueError(f"{p}: is not an .npz file (not a zip archive); {_LAYOUTS}")
    try:
        with zipfile.ZipFile(p) as zf:
            names = [n.removesuffix(".npy") for n in zf.namelist()]
            if "labels" not in names:
                raise ValueError(f"{p}: has no array 'labels' (found {', '.join(names) or 'none'})")
            with zf.open("labels.npy") as f:
                version = np.lib.format.read_magic(f)
                if version == (1, 0):
                    shape, _, dtype = np.lib.format.read_array_header_1_0(f)
                else:
                    shape, _, dtype = np.lib.format.read_array_header_2_0(f)
    except NPZ_ERRORS as err:
        if isinstance(err, ValueError) and str(err).startswith(str(p)):
            raise
        raise ValueError(f"{p}: cannot be read as an .npz file ({type(err).__name__}: {err})") from None
    if dtype.hasobject:
        raise ValueError(f"{p}: 'labels' holds pickled Python objects, which GeoCon never loads")
    if len(shape) != 3 or dtype.kind not in "iub":
        raise ValueError(f"{p}: 'labels' must be integer, of shape (T, h, w), got {dtype} {shape}")


def check_masks_path(path: str | Path) -> str:
    """The layout of the masks at ``path`` (``"npz"``, ``"label_images"`` or ``"object_folders"``),
    checked as far as it can be without the clip (exists, is a layout, its first file reads), so a
    wrong path fails before any frame is decoded; ``ValueError`` naming the problem."""
    p = Path(path)
    if not p.exists():
        raise ValueError(f"{p}: masks path does not exist")
    if not p.is_dir():  # a FIFO, a device or an archive past its bound is refused unread
        regular_file(p, MASKS_ARCHIVE)
    if p.is_file():
        if p.suffix.lower() != ".npz":
            raise ValueError(f"{p}: not a masks layout; {_LAYOUTS}")
        _check_npz_header(p)
        return "npz"
    if not p.is_dir():
        raise ValueError(f"{p}: not a masks layout; {_LAYOUTS}")
    pngs = sorted(c for c in p.iterdir() if c.suffix.lower() == ".png" and not c.is_dir())
    if pngs:
        _read_png(pngs[0])
        return "label_images"
    dirs = _object_dirs(p)
    if not dirs:
        raise ValueError(f"{p}: not a masks layout; {_LAYOUTS}")
    return "object_folders"


class ExternalMasks(Coverage):
    """Masks from files (``name = "external"``, lookahead 0); layouts in the module docstring.

    Labels do not depend on the pushed frames: ``labels(t)`` may be asked for any frame at any
    time (``push`` only checks the frame order)."""

    name = "external"
    lookahead = 0

    def __init__(self, path: str | Path, info: ClipInfo) -> None:
        super().__init__(info)
        self.path = Path(path)
        T = info.num_frames
        self._files: list[Path] | None = None
        self._objects: list[tuple[int, list[Path]]] | None = None
        self._array: np.ndarray | None = None
        self._next = 0
        self._cache: tuple[int, np.ndarray] | None = None
        p = self.path
        self.layout = check_masks_path(p)
        if self.layout == "npz":
            self._array = self._load_npz(p, info)
        elif self.layout == "label_images":
            self._files = _frame_files(p, T, "label images")
            _check_size(_read_png(self._files[0]), info, str(self._files[0]))
        else:
            self._objects = [(oid, _frame_files(d, T, "masks")) for oid, d in _object_dirs(p)]
            for _, files in self._objects:
                _check_size(_read_png(files[0]), info, str(files[0]))

    @staticmethod
    def _load_npz(p: Path, info: ClipInfo) -> np.ndarray:
        try:  # the header was checked by check_masks_path; the data may still be damaged
            with np.load(p, allow_pickle=False) as z:
                names = z.files
                arr = z["labels"] if "labels" in names else None
        except NPZ_ERRORS as err:
            if isinstance(err, ValueError) and "pickle" in str(err):
                raise ValueError(f"{p}: 'labels' holds pickled Python objects, which GeoCon never loads") from None
            raise ValueError(f"{p}: cannot be read as an .npz file ({type(err).__name__}: {err})") from None
        if arr is None:
            raise ValueError(f"{p}: has no array 'labels' (found {', '.join(names) or 'none'})")
        if arr.ndim != 3:
            raise ValueError(f"{p}: 'labels' must have shape (T, h, w), got {arr.shape}")
        if arr.dtype.kind not in "iub":
            raise ValueError(f"{p}: 'labels' must be integer, got {arr.dtype}")
        if arr.shape[0] != info.num_frames:
            raise ValueError(f"{p}: 'labels' has {arr.shape[0]} frames but the clip has {info.num_frames}")
        _check_size(arr[0], info, f"{p} 'labels'")
        return _check_ids(arr, f"{p} 'labels'")

    def _source_labels(self, t: int) -> np.ndarray:
        if self._array is not None:
            return self._array[t]
        if self._files is not None:
            f = self._files[t]
            img = _read_png(f)
            _check_size(img, self.info, str(f))
            return _check_ids(img, str(f))
        assert self._objects is not None
        w, h = self.info.source_size
        out = np.zeros((h, w), np.uint8)
        for oid, files in self._objects:  # ascending ids: the higher id wins where they overlap
            img = _read_png(files[t])
            _check_size(img, self.info, str(files[t]))
            out[img != 0] = oid
        return out

    def push(self, frame: Frame) -> None:
        if frame.index != self._next:
            raise ValueError(f"frames must be pushed in order: expected frame {self._next}, got {frame.index}")
        self._next += 1

    def finish(self) -> None:
        pass

    def labels(self, t: int) -> np.ndarray:
        if not 0 <= t < self.info.num_frames:
            raise IndexError(f"frame {t} is outside 0..{self.info.num_frames - 1}")
        if self._cache is not None and self._cache[0] == t:
            return self._cache[1]
        lab = labels_to_canvas(self._source_labels(t), self.info)
        lab.flags.writeable = False
        self._cache = (t, lab)
        self._record(t, lab)
        return lab

    def release(self, t: int) -> None:
        if self._cache is not None and self._cache[0] < t:
            self._cache = None

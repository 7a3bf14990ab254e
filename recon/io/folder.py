"""The on-disk scan format: a folder of images, masks, camera poses and the calibration.

Layout (``docs/replay.md`` is the full specification)::

    SCAN/
      camera.json      {"width", "height", "fx", "fy", "cx", "cy", "distortion_model", "distortion"}
      frames.jsonl     one JSON object per line and frame, in time order:
                       {"time": s, "T_world_camera": 4x4 rows, "image": "images/000000.png",
                        "mask": "masks/000000.png", "flow": "flow/000000.png"}
                       ("mask" and "flow" optional, "image" null = pose only)
      images/          PNG or JPEG colour images (raw, i.e. still distorted)
      masks/           optional PNG masks, non-zero = branch
      flow/            optional optical-flow pictures (colour wheel, any size; see below)
      metadata.json    optional: modeler seed and config, ground truth file, provenance
      truth.json       optional ground truth (``branch_gym`` TreeGT JSON)

:class:`ScanWriter` writes a scan (into a temp folder renamed on success: never half written);
:class:`ScanFolder` validates and reads one, undistorting images and masks.

Optical-flow pictures (for a segmenter that reads them, ``recon.segmentation``): a frame's
``"flow"`` names its picture; without that field a file ``<image without suffix>_flow.png``
beside the image is taken when it exists (``images/000000_flow.png``, the layout of the
authors' real frames ``N.png`` + ``N_flow.png``). A picture is read as an image and converted
BGR -> RGB (what ``cv2.imwrite`` of a BGR array stores); one written with ``cv2.imwrite`` of an
RGB array has red and blue exchanged, which the replay undoes on request
(``recon.replay --flow-red-blue-swapped``). A picture of another size than the image is resized
to it (``cv2.INTER_AREA``), then undistorted like the image (bilinear; the flow vectors it codes
are not re-projected).
"""

from __future__ import annotations

import json
import logging
import math
from collections.abc import Iterator
from contextlib import ExitStack
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np

from recon.camera import CameraIntrinsics
from recon.frame import Frame
from recon.io.atomic import atomic_output_dir, check_output_dir
from recon.io.distortion import CameraModel, Undistorter

logger = logging.getLogger(__name__)

CAMERA_FILE = "camera.json"
FRAMES_FILE = "frames.jsonl"
METADATA_FILE = "metadata.json"
TRUTH_FILE = "truth.json"
FORMAT_NAME = "recon-scan"
FORMAT_VERSION = 1
IMAGE_FORMATS = ("png", "jpg")


class ScanFormatError(ValueError):
    """A scan (folder or bag) that cannot be read; the message names the file, topic or frame."""


@dataclass(frozen=True)
class ScanFormatConfig:
    """Tolerances of the scan reader.

    Attributes:
        rigid_tolerance: A pose whose rotation block deviates from orthonormal by at most this
            (max abs entry of ``R R^T - I``) is re-orthonormalised (poses printed with 6
            decimals); larger deviations, reflections or a bad last row are errors.
        mask_threshold: 8-bit mask pixels above this are branch (masks holding only 0 and 1 use
            "non-zero").
    """

    rigid_tolerance: float = 1e-5
    mask_threshold: int = 127

    def __post_init__(self) -> None:
        if not self.rigid_tolerance > 0:
            raise ValueError("ScanFormatConfig.rigid_tolerance must be positive")
        if not 0 <= self.mask_threshold < 255:
            raise ValueError("ScanFormatConfig.mask_threshold must be in [0, 255)")


@dataclass
class LoadedFrame:
    """One frame of a scan source, decoded (or the reason it cannot be used).

    Attributes:
        index: Position in the source (0-based, every frame counted, skipped ones included).
        time_s: Acquisition time in seconds.
        where: Where it came from, for reports ("frames.jsonl line 4", "/camera/... msg 12").
        T_world_camera: (4, 4) camera pose (OpenCV axes, camera to world), or None (skipped).
        rgb: (H, W, 3) uint8 undistorted image; None for a pose-only or skipped frame.
        mask: (H, W) bool undistorted mask, or None (no mask recorded).
        skip_reason: Why the frame cannot be used, or None.
        skip_kind: The reason's category for counting ("no pose", "cannot read image", ...).
        flow_image: (H, W, 3) uint8 RGB optical-flow picture of the frame as recorded (resized
            to the image and undistorted), or None: none recorded, or not asked for
            (``frames(load_flow=False)``).
    """

    index: int
    time_s: float
    where: str
    T_world_camera: np.ndarray | None = None
    rgb: np.ndarray | None = None
    mask: np.ndarray | None = None
    skip_reason: str | None = None
    skip_kind: str | None = None
    flow_image: np.ndarray | None = None

    def skip(self, kind: str, reason: str) -> LoadedFrame:
        """Mark the frame unusable (image, mask, flow picture and pose dropped); returns it."""
        self.rgb = self.mask = self.T_world_camera = self.flow_image = None
        self.skip_kind, self.skip_reason = kind, reason
        return self

    @property
    def pose_only(self) -> bool:
        """A usable frame that carries a pose but no image."""
        return self.skip_reason is None and self.rgb is None

    def to_frame(self, intrinsics: CameraIntrinsics, mask: np.ndarray | None = None) -> Frame:
        """The pipeline's :class:`recon.Frame` (``mask`` overrides the recorded one).

        Raises:
            ValueError: a skipped frame, or an image frame with no mask.
        """
        if self.skip_reason is not None or self.T_world_camera is None:
            raise ValueError(f"frame {self.index} ({self.where}) is unusable: {self.skip_reason}")
        if self.rgb is None:
            return Frame.pose_only(self.T_world_camera, intrinsics, self.time_s)
        mask = self.mask if mask is None else mask
        if mask is None:
            raise ValueError(f"frame {self.index} ({self.where}) has no mask")
        return Frame(self.rgb, mask, self.T_world_camera, intrinsics, self.time_s)


def as_rigid_pose(T: object, tolerance: float = 1e-5) -> np.ndarray:
    """Validate a (4, 4) rigid transform; re-orthonormalise a rotation within ``tolerance``.

    Returns:
        (4, 4) float pose; the input's values unchanged when already orthonormal to 1e-9.

    Raises:
        ValueError: wrong shape, non-finite values, a last row other than [0, 0, 0, 1], a
            reflection or a rotation block further than ``tolerance`` from orthonormal.
    """
    try:
        T = np.array(T, dtype=float)
    except (TypeError, ValueError) as error:
        raise ValueError(f"T_world_camera is not a numeric 4x4 matrix ({error})") from None
    if T.shape != (4, 4):
        raise ValueError(f"T_world_camera must be 4x4, got shape {T.shape}")
    if not np.all(np.isfinite(T)):
        raise ValueError("T_world_camera holds NaN or infinite values")
    if not np.allclose(T[3], [0.0, 0.0, 0.0, 1.0], atol=1e-9):
        raise ValueError(f"T_world_camera last row must be [0, 0, 0, 1], got {T[3].tolist()}")
    R = T[:3, :3]
    error = float(np.abs(R @ R.T - np.eye(3)).max())
    det = float(np.linalg.det(R))
    if det <= 0:
        raise ValueError(f"T_world_camera is not a rigid transform: rotation determinant {det:.3g}")
    if error > tolerance:
        raise ValueError(
            "T_world_camera is not a rigid transform: its rotation block deviates from "
            f"orthonormal by {error:.3g} (tolerance {tolerance:g})"
        )
    if error > 1e-9:
        U, _, Vt = np.linalg.svd(R)
        T[:3, :3] = U @ Vt
    T[3] = [0.0, 0.0, 0.0, 1.0]
    return T


def read_mask_file(path: Path, threshold: int) -> np.ndarray | None:
    """(H, W) bool mask from an image file, or None when it cannot be decoded."""
    raw = cv2.imread(str(path), cv2.IMREAD_GRAYSCALE)
    if raw is None:
        return None
    return mask_from_array(raw, threshold)


def mask_from_array(raw: np.ndarray, threshold: int) -> np.ndarray:
    """(H, W) bool from an 8/16-bit grey mask: 0/1 masks non-zero, 0/255 above ``threshold``."""
    if raw.ndim == 3:
        raw = raw.max(axis=2)
    return raw > (0 if raw.max(initial=0) <= 1 else threshold)


def flow_picture_from_array(
    image: np.ndarray, width: int, height: int, undistorter: Undistorter
) -> np.ndarray:
    """A recorded flow picture on the frame's grid: resized (INTER_AREA), then undistorted.

    Args:
        image: (h, w, 3) uint8 RGB picture as recorded (any size).
        width: Width (px) of the raw frames.
        height: Height (px) of the raw frames.
        undistorter: The frames' undistorter.

    Returns:
        (height, width, 3) uint8 RGB picture.

    Raises:
        ValueError: ``image`` is not an (h, w, 3) uint8 array.
    """
    if image.dtype != np.uint8 or image.ndim != 3 or image.shape[2] != 3:
        raise ValueError(
            f"a flow picture must be an (H, W, 3) uint8 colour image, got {image.dtype} "
            f"{image.shape}"
        )
    if image.shape[:2] != (height, width):
        image = cv2.resize(image, (width, height), interpolation=cv2.INTER_AREA)
    return undistorter.image(image)


def _load_json(path: Path) -> object:
    if not path.is_file():
        raise ScanFormatError(f"{path}: file not found")
    try:
        return json.loads(path.read_text())
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as error:
        raise ScanFormatError(f"{path}: cannot read JSON ({error})") from None


def load_camera(path: str | Path) -> CameraModel:
    """Read ``camera.json``.

    Raises:
        ScanFormatError: missing, unreadable or malformed (the message names the file).
    """
    path = Path(path)
    try:
        return CameraModel.from_dict(_load_json(path))
    except ScanFormatError:
        raise
    except ValueError as error:
        raise ScanFormatError(f"{path}: {error}") from None


@dataclass(frozen=True)
class FrameRecord:
    """One parsed line of ``frames.jsonl``.

    Attributes:
        index: Frame index (0-based).
        line: Line number in the file (1-based).
        time_s: Acquisition time, seconds.
        T_world_camera: (4, 4) pose.
        image: Image path relative to the scan folder, or None (pose-only frame).
        mask: Mask path relative to the scan folder, or None.
        flow: Optical-flow picture path relative to the scan folder (``"flow"``), or None
            (then ``<image without suffix>_flow.png`` if it exists, module docstring).
    """

    index: int
    line: int
    time_s: float
    T_world_camera: np.ndarray
    image: str | None
    mask: str | None
    flow: str | None = None


def parse_frames(path: Path, config: ScanFormatConfig) -> list[FrameRecord]:
    """Parse and validate ``frames.jsonl`` (fields, rigid poses, increasing times).

    Raises:
        ScanFormatError: naming the file, line and frame of the first problem.
    """
    if not path.is_file():
        raise ScanFormatError(f"{path}: file not found")
    try:
        lines = path.read_text().splitlines()
    except (OSError, UnicodeDecodeError) as error:
        raise ScanFormatError(f"{path}: cannot read ({error})") from None
    records: list[FrameRecord] = []
    for number, text in enumerate(lines, start=1):
        if not text.strip():
            continue
        where = f"{path}:{number} (frame {len(records)})"
        try:
            data = json.loads(text)
        except json.JSONDecodeError as error:
            raise ScanFormatError(f"{where}: not valid JSON ({error})") from None
        if not isinstance(data, dict):
            raise ScanFormatError(f"{where}: expected a JSON object")
        for key in ("time", "T_world_camera"):
            if key not in data:
                raise ScanFormatError(f"{where}: missing field {key!r}")
        time_s = data["time"]
        if isinstance(time_s, bool) or not isinstance(time_s, int | float):
            raise ScanFormatError(f"{where}: time must be a number, got {time_s!r}")
        if not math.isfinite(time_s):
            raise ScanFormatError(f"{where}: time must be finite, got {time_s}")
        try:
            T = as_rigid_pose(data["T_world_camera"], config.rigid_tolerance)
        except ValueError as error:
            raise ScanFormatError(f"{where}: {error}") from None
        image, mask, flow = data.get("image"), data.get("mask"), data.get("flow")
        for key, value in (("image", image), ("mask", mask), ("flow", flow)):
            if value is not None and not (isinstance(value, str) and value):
                raise ScanFormatError(f"{where}: {key} must be a path string or null")
        if image is None and mask is not None:
            raise ScanFormatError(f"{where}: a mask without an image")
        if image is None and flow is not None:
            raise ScanFormatError(f"{where}: a flow picture without an image")
        if records and not time_s > records[-1].time_s:
            raise ScanFormatError(
                f"{where}: time {time_s} s is not after the previous frame's "
                f"{records[-1].time_s} s: times must increase"
            )
        records.append(FrameRecord(len(records), number, float(time_s), T, image, mask, flow))
    if not records:
        raise ScanFormatError(f"{path}: no frames")
    return records


class ScanFolder:
    """A scan folder, validated on opening; :meth:`frames` decodes and undistorts lazily.

    Args:
        path: The scan folder.
        config: Reader tolerances.
        skip_bad_frames: Report a missing, unreadable or wrongly sized image or mask as a skipped
            frame (:attr:`LoadedFrame.skip_reason`) instead of raising.

    Raises:
        ScanFormatError: a malformed ``camera.json``, ``frames.jsonl`` or ``metadata.json``, or
            (unless ``skip_bad_frames``) a missing image or mask file.
    """

    def __init__(
        self,
        path: str | Path,
        config: ScanFormatConfig | None = None,
        skip_bad_frames: bool = False,
    ) -> None:
        self.path = Path(path)
        self.config = config or ScanFormatConfig()
        self.skip_bad_frames = skip_bad_frames
        if not self.path.is_dir():
            raise ScanFormatError(f"{self.path}: scan folder not found")
        self.camera = load_camera(self.path / CAMERA_FILE)
        self.undistorter = Undistorter(self.camera)
        self.records = parse_frames(self.path / FRAMES_FILE, self.config)
        meta_path = self.path / METADATA_FILE
        self.metadata: dict = {}
        if meta_path.exists():
            meta = _load_json(meta_path)
            if not isinstance(meta, dict):
                raise ScanFormatError(f"{meta_path}: expected a JSON object")
            self.metadata = meta
        self.skipped_at_open = 0
        if not skip_bad_frames:
            missing = self._missing_files()
            if missing:
                more = f" (and {len(missing) - 5} more)" if len(missing) > 5 else ""
                raise ScanFormatError("missing file(s): " + "; ".join(missing[:5]) + more)

    @property
    def name(self) -> str:
        return str(self.path)

    @property
    def intrinsics(self) -> CameraIntrinsics:
        """Intrinsics of the undistorted frames."""
        return self.undistorter.intrinsics

    @property
    def has_masks(self) -> bool:
        """Every frame with an image names a mask."""
        return all(r.mask is not None for r in self.records if r.image is not None)

    @property
    def frames_without_mask(self) -> list[int]:
        return [r.index for r in self.records if r.image is not None and r.mask is None]

    def __len__(self) -> int:
        return len(self.records)

    def truth_path(self) -> Path | None:
        """The ground truth named by the metadata (or ``truth.json``), if present."""
        name = self.metadata.get("truth", TRUTH_FILE)
        path = self.path / str(name)
        return path if path.is_file() else None

    def _missing_files(self) -> list[str]:
        missing = []
        for r in self.records:
            for key in ("image", "mask"):
                name = getattr(r, key)
                if name is not None and not (self.path / name).is_file():
                    missing.append(f"{key} {self.path / name} ({FRAMES_FILE} line {r.line})")
        return missing

    def flow_path(self, record: FrameRecord) -> Path | None:
        """The flow picture of a frame: its ``"flow"``, else ``<image>_flow.png`` if present.

        Returns:
            The path (named ones whether they exist or not), or None: no image, or none named
            and no ``_flow.png`` beside the image.
        """
        if record.flow is not None:
            return self.path / record.flow
        if record.image is None:
            return None
        image = self.path / record.image
        beside = image.with_name(f"{image.stem}_flow.png")
        return beside if beside.is_file() else None

    def frames(self, load_masks: bool = True, load_flow: bool = False) -> Iterator[LoadedFrame]:
        """Decode the frames in time order.

        Args:
            load_masks: Read the mask files (False when a segmenter replaces them).
            load_flow: Read the optical-flow pictures into :attr:`LoadedFrame.flow_image`
                (module docstring). A named picture that is missing or unreadable raises
                :class:`ScanFormatError`; with ``skip_bad_frames`` it is logged and the frame
                keeps no picture (it stays usable).

        Yields:
            :class:`LoadedFrame` per line; bad frames with a ``skip_reason`` when
            ``skip_bad_frames`` (else they raise :class:`ScanFormatError`).
        """
        k = self.camera.intrinsics
        for r in self.records:
            where = f"{FRAMES_FILE} line {r.line}"
            out = LoadedFrame(r.index, r.time_s, where, r.T_world_camera)
            if r.image is None:
                yield out
                continue
            problem = kind = None
            rgb = mask = None
            image_path = self.path / r.image
            bgr = cv2.imread(str(image_path), cv2.IMREAD_COLOR)
            if bgr is None:
                kind, problem = "cannot read image", f"cannot read image {image_path}"
            elif bgr.shape[:2] != (k.height, k.width):
                kind = f"image size disagrees with {CAMERA_FILE}"
                problem = (
                    f"image {image_path} is {bgr.shape[1]}x{bgr.shape[0]} but {CAMERA_FILE} "
                    f"says {k.width}x{k.height}"
                )
            else:
                rgb = self.undistorter.image(cv2.cvtColor(bgr, cv2.COLOR_BGR2RGB))
            if problem is None and load_masks and r.mask is not None:
                mask_path = self.path / r.mask
                raw = read_mask_file(mask_path, self.config.mask_threshold)
                if raw is None:
                    kind, problem = "cannot read mask", f"cannot read mask {mask_path}"
                elif raw.shape != (k.height, k.width):
                    kind = f"mask size disagrees with {CAMERA_FILE}"
                    problem = (
                        f"mask {mask_path} is {raw.shape[1]}x{raw.shape[0]} but {CAMERA_FILE} "
                        f"says {k.width}x{k.height}"
                    )
                else:
                    mask = self.undistorter.mask(raw)
            if problem is not None:
                if not self.skip_bad_frames:
                    raise ScanFormatError(f"{problem} ({where}, frame {r.index})")
                logger.warning("skipping frame %d: %s", r.index, problem)
                yield out.skip(kind, problem)
                continue
            out.rgb, out.mask = rgb, mask
            if load_flow:
                out.flow_image = self._read_flow(r, where)
            yield out

    def _read_flow(self, record: FrameRecord, where: str) -> np.ndarray | None:
        """(H, W, 3) uint8 RGB flow picture of a frame (module docstring), or None."""
        path = self.flow_path(record)
        if path is None:
            return None
        bgr = cv2.imread(str(path), cv2.IMREAD_COLOR) if path.is_file() else None
        if bgr is None:
            problem = f"cannot read flow picture {path} ({where}, frame {record.index})"
            if not self.skip_bad_frames:
                raise ScanFormatError(problem)
            logger.warning("frame %d has no flow picture: %s", record.index, problem)
            return None
        k = self.camera.intrinsics
        rgb = cv2.cvtColor(bgr, cv2.COLOR_BGR2RGB)
        return flow_picture_from_array(rgb, k.width, k.height, self.undistorter)


class ScanWriter:
    """Writes a scan folder; the folder appears only when :meth:`commit` succeeds.

    Use as a context manager (commits on normal exit, discards on an exception)::

        with ScanWriter("scan", CameraModel(intrinsics)) as writer:
            for frame in frames:
                writer.add_frame(frame)

    Args:
        out_dir: The scan folder to create.
        camera: Calibration of the images written (``distortion`` of the raw images).
        image_format: "png" (lossless: a replay reproduces the model exactly) or "jpg".
        jpeg_quality: JPEG quality 0-100.
        overwrite: Replace an existing ``out_dir`` once the new one is complete.

    Raises:
        OutputExistsError: ``out_dir`` exists and ``overwrite`` is False.
    """

    def __init__(
        self,
        out_dir: str | Path,
        camera: CameraModel,
        image_format: str = "png",
        jpeg_quality: int = 95,
        overwrite: bool = False,
    ) -> None:
        if image_format not in IMAGE_FORMATS:
            raise ValueError(f"image_format must be one of {IMAGE_FORMATS}, got {image_format!r}")
        if not 0 <= jpeg_quality <= 100:
            raise ValueError(f"jpeg_quality must be in [0, 100], got {jpeg_quality}")
        self.out_dir = check_output_dir(out_dir, overwrite)
        self.camera = camera
        self.image_format = image_format
        self.jpeg_quality = jpeg_quality
        self.overwrite = overwrite
        self.metadata: dict = {"format": FORMAT_NAME, "version": FORMAT_VERSION}
        self.n_frames = 0
        self._last_time: float | None = None
        self._stack: ExitStack | None = None
        self._tmp: Path | None = None
        self._lines = None

    # ------------------------------------------------------------------ lifecycle
    def open(self) -> ScanWriter:
        if self._stack is not None:
            raise RuntimeError("ScanWriter is already open")
        self._stack = ExitStack()
        self._tmp = self._stack.enter_context(atomic_output_dir(self.out_dir, self.overwrite))
        (self._tmp / "images").mkdir()
        (self._tmp / "masks").mkdir()
        self._lines = self._stack.enter_context(open(self._tmp / FRAMES_FILE, "w"))
        return self

    def commit(self) -> Path:
        """Write ``camera.json`` and ``metadata.json`` and move the folder into place."""
        stack = self._require_open()
        if self.n_frames == 0:
            self.abort()
            raise ScanFormatError(f"{self.out_dir}: no frames were written")
        self._write_json(CAMERA_FILE, self.camera.to_dict())
        self._write_json(METADATA_FILE, self.metadata)
        self._stack = None
        stack.close()  # closes frames.jsonl, then renames the temp folder
        logger.info("wrote scan %s (%d frames)", self.out_dir, self.n_frames)
        return self.out_dir

    def abort(self) -> None:
        """Discard everything written so far."""
        if self._stack is None:
            return
        stack, self._stack = self._stack, None
        stack.__exit__(_AbortError, _AbortError(), None)  # the atomic folder deletes its files

    def __enter__(self) -> ScanWriter:
        return self.open()

    def __exit__(self, exc_type, exc, tb) -> None:
        if self._stack is None:
            return
        if exc_type is None:
            self.commit()
        else:
            self.abort()

    # ------------------------------------------------------------------ content
    @property
    def tmp_dir(self) -> Path:
        """The folder being written (renamed to ``out_dir`` on commit)."""
        self._require_open()
        assert self._tmp is not None
        return self._tmp

    def add(
        self,
        time_s: float,
        T_world_camera: np.ndarray,
        rgb: np.ndarray | None = None,
        mask: np.ndarray | None = None,
        flow_image: np.ndarray | None = None,
    ) -> None:
        """Append one frame.

        Args:
            time_s: Acquisition time (s), after the previous frame's.
            T_world_camera: (4, 4) rigid camera pose.
            rgb: (H, W, 3) uint8 image matching the camera, or None for a pose-only frame.
            mask: (H, W) bool mask, or None.
            flow_image: (h, w, 3) uint8 RGB optical-flow picture of the frame (any size), or
                None; written as ``flow/NNNNNN.png`` with its colours as given (read back
                as RGB, no red-blue exchange).

        Raises:
            ValueError: non-increasing time, a non-rigid pose, wrong image or mask size, or a
                flow picture that is not (h, w, 3) uint8 or has no image.
        """
        self._require_open()
        index = self.n_frames
        if not math.isfinite(time_s):
            raise ValueError(f"frame {index}: time must be finite, got {time_s}")
        if self._last_time is not None and not time_s > self._last_time:
            raise ValueError(
                f"frame {index}: time {time_s} s is not after the previous {self._last_time} s"
            )
        T = as_rigid_pose(T_world_camera)
        k = self.camera.intrinsics
        line: dict = {"time": float(time_s), "T_world_camera": T.tolist(), "image": None}
        if rgb is not None:
            rgb = np.asarray(rgb)
            if rgb.shape != (k.height, k.width, 3) or rgb.dtype != np.uint8:
                raise ValueError(
                    f"frame {index}: rgb must be ({k.height}, {k.width}, 3) uint8, "
                    f"got {rgb.shape} {rgb.dtype}"
                )
            name = f"images/{index:06d}.{self.image_format}"
            jpg = self.image_format == "jpg"
            params = [cv2.IMWRITE_JPEG_QUALITY, self.jpeg_quality] if jpg else []
            self._imwrite(name, cv2.cvtColor(rgb, cv2.COLOR_RGB2BGR), params)
            line["image"] = name
        if mask is not None:
            if rgb is None:
                raise ValueError(f"frame {index}: a mask without an image")
            mask = np.asarray(mask)
            if mask.shape != (k.height, k.width):
                raise ValueError(
                    f"frame {index}: mask must be ({k.height}, {k.width}), got {mask.shape}"
                )
            name = f"masks/{index:06d}.png"
            self._imwrite(name, np.where(mask.astype(bool), 255, 0).astype(np.uint8), [])
            line["mask"] = name
        if flow_image is not None:
            if rgb is None:
                raise ValueError(f"frame {index}: a flow picture without an image")
            flow_image = np.asarray(flow_image)
            if flow_image.ndim != 3 or flow_image.shape[2] != 3 or flow_image.dtype != np.uint8:
                raise ValueError(
                    f"frame {index}: flow_image must be (h, w, 3) uint8, got "
                    f"{flow_image.shape} {flow_image.dtype}"
                )
            name = f"flow/{index:06d}.png"
            (self.tmp_dir / "flow").mkdir(exist_ok=True)
            self._imwrite(name, cv2.cvtColor(flow_image, cv2.COLOR_RGB2BGR), [])
            line["flow"] = name
        assert self._lines is not None
        self._lines.write(json.dumps(line) + "\n")
        self._last_time = float(time_s)
        self.n_frames += 1

    def add_frame(self, frame: Frame) -> None:
        """Append a :class:`recon.Frame` (pose-only frames as lines without an image)."""
        if frame.timestamp_s is None:
            raise ValueError("the scan format needs frame.timestamp_s")
        if frame.has_image:
            self.add(frame.timestamp_s, frame.T_world_camera, frame.rgb, frame.mask)
        else:
            self.add(frame.timestamp_s, frame.T_world_camera)

    def write_file(self, name: str, text: str) -> Path:
        """Write an extra file (e.g. ``truth.json``) into the scan folder."""
        path = self.tmp_dir / name
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_text(text)
        return path

    # ------------------------------------------------------------------ helpers
    def _require_open(self) -> ExitStack:
        if self._stack is None:
            raise RuntimeError("ScanWriter is not open: use it as a context manager or open()")
        return self._stack

    def _imwrite(self, name: str, image: np.ndarray, params: list[int]) -> None:
        path = self.tmp_dir / name
        if not cv2.imwrite(str(path), image, params):
            raise OSError(f"cannot write {path}")

    def _write_json(self, name: str, data: dict) -> None:
        (self.tmp_dir / name).write_text(json.dumps(data, indent=1))


class _AbortError(Exception):
    """Raised inside :meth:`ScanWriter.abort` so the atomic folder discards its content."""

"""A dataset root (a local path or any fsspec URL) and the one place that knows its layout.

Every write of a whole file goes through :meth:`Store.write_bytes`, which writes to a hidden
temporary name in the same directory and renames it into place, so a crash never leaves a
half-written file under its final name (readers glob ``*.parquet``/``*.glb`` and never see the
``.tmp-*`` names).
"""

from __future__ import annotations

import functools
import hashlib
import os
import posixpath
import tempfile
import uuid
from dataclasses import dataclass

import fsspec

# Store layout (docs/architecture.md "Store layout"): table name -> directory of Parquet files.
TABLE_DIRS: dict[str, str] = {
    "assets": "admesh/assets",
    "parts": "admesh/parts",
    "quarantine": "admesh/quarantine",
    "placements": "scenes/placements",
    "towns": "scenes/towns",
    "sequences": "scenes/sequences",
    "frames": "scenes/frames",
    "sensor_poses": "scenes/sensor_poses",
    "actors": "scenes/actors",
    "skeletons": "scenes/skeletons",
    "ego_states": "scenes/ego_states",
    "quality": "metrics/quality",
    "rectification": "metrics/rectification",
    "lidar_agreement": "metrics/lidar_agreement",
    "quality_classes": "metrics/quality_classes",
    "statistics_frames": "metrics/statistics_frames",
    "statistics_classes": "metrics/statistics_classes",
    "statistics_assets": "metrics/statistics_assets",
    "runs": "catalog/runs",
}
OCCUPANCY_ZARR = "occupancy.zarr"
SENSORS_ZARR = "sensors.zarr"
LIDAR_DIR = "lidar"
LIDAR_RECORDED_DIR = "lidar_recorded"  # a recording's own LiDAR scans (catalog/sensors.py RecordedLidarStore)
ADMESH_MESHES = "admesh/meshes"
ADMESH_TEXTURES = "admesh/textures"
SCENE_MESHES = "scenes/meshes"
PLAN_FILE = "plan.yaml"  # the root's remembered plan (catalog/plan.py)


class StoreError(Exception):
    """A store problem a user can fix (unwritable root, missing input...)."""


def fingerprint_bytes(data: bytes) -> str:
    """Content fingerprint of a file: ``sha256:`` and the first 24 hex digits."""
    return "sha256:" + hashlib.sha256(data).hexdigest()[:24]


@dataclass(frozen=True)
class Store:
    """A dataset root. ``url`` is a local path or an fsspec URL such as ``memory://ds``."""

    url: str

    def __post_init__(self) -> None:
        url = self.url
        if "://" not in url:
            # a local path is a path: '::', '#', '?' and '%' are characters of it, never URL syntax
            url = os.path.abspath(os.path.expanduser(url))
        elif "::" in url:
            # fsspec would chain filesystems and root the dataset in the first one (another
            # dataset's folder): carlaocc roots are one filesystem, so such a URL is refused
            raise ValueError(f"{url}: '::' chains filesystems in an fsspec URL, which a dataset root cannot be; give "
                             "one path or one URL (s3://bucket/prefix, file:///abs/path)")
        object.__setattr__(self, "url", url.rstrip("/") or "/")

    # -- filesystem -------------------------------------------------------------------------
    # resolved once per Store object (a chunk read asks for both: url_to_fs costs ~0.1 ms)
    @functools.cached_property
    def fs(self) -> fsspec.AbstractFileSystem:
        if "://" not in self.url:  # a plain local path: never parsed as a URL
            return fsspec.filesystem("file")
        fs, _ = fsspec.core.url_to_fs(self.url, **self.storage_options)
        return fs

    @property
    def storage_options(self) -> dict:
        """What the filesystem is opened with: an object store's listings are never cached (other
        processes write the same root: a cached listing would hide their chunks); credentials and
        endpoint come from the environment (``AWS_ENDPOINT_URL``, ``AWS_ACCESS_KEY_ID``...)."""
        return {} if self.is_local else {"use_listings_cache": False}

    @property
    def is_object_store(self) -> bool:
        """Keys, not directories (S3, GCS, Azure, memory://): nothing to create before a write,
        and one PUT of a whole file is atomic."""
        return "://" in self.url and self.url.split("://", 1)[0] in ("s3", "s3a", "gs", "gcs", "az", "abfs", "memory")

    @property
    def in_memory(self) -> bool:
        """A ``memory://`` root: it lives in this process only (worker processes cannot see it)."""
        return self.url.startswith("memory://")

    @functools.cached_property
    def root(self) -> str:
        if "://" not in self.url:  # already absolute and normalised by __post_init__
            return self.url
        _, path = fsspec.core.url_to_fs(self.url)
        return path

    @property
    def is_local(self) -> bool:
        return "://" not in self.url or self.url.startswith("file://")

    def path(self, rel: str) -> str:
        """Filesystem path of a store-relative path."""
        return posixpath.join(self.root, rel) if rel else self.root

    def uri(self, rel: str) -> str:
        """URL (or absolute local path) of a store-relative path."""
        return f"{self.url}/{rel}" if rel else self.url

    def exists(self, rel: str) -> bool:
        return self.fs.exists(self.path(rel))

    def read_bytes(self, rel: str) -> bytes:
        try:
            return self.fs.cat_file(self.path(rel))
        except FileNotFoundError:
            raise StoreError(f"missing in the store {self.url}: {rel}") from None

    def write_bytes(self, rel: str, data: bytes) -> str:
        """Write a whole file atomically (on a disk: temporary name, then rename; on an object
        store: one PUT, which readers see whole or not at all); returns its fingerprint."""
        fs, final = self.fs, self.path(rel)
        if not self.is_local:
            if not self.is_object_store:  # e.g. sftp: a file's directory must exist
                fs.makedirs(posixpath.dirname(final), exist_ok=True)
            fs.pipe_file(final, bytes(data))
            return fingerprint_bytes(data)
        parent = posixpath.dirname(final)
        fs.makedirs(parent, exist_ok=True)
        tmp = posixpath.join(parent, f".tmp-{uuid.uuid4().hex}-{posixpath.basename(final)}.partial")
        try:
            with fs.open(tmp, "wb") as fh:
                fh.write(data)
            os.replace(tmp, final)  # atomic on POSIX
        finally:
            if fs.exists(tmp):
                fs.rm(tmp)
        return fingerprint_bytes(data)

    def fingerprint(self, rel: str) -> str | None:
        """Fingerprint of a stored file, or None when it does not exist."""
        try:
            return fingerprint_bytes(self.fs.cat_file(self.path(rel)))
        except FileNotFoundError:
            return None

    def find(self, path: str, detail: bool = False):
        """``fs.find`` of an absolute filesystem path, empty when nothing is there: one listing
        (an object store answers ``exists`` of a prefix with a listing of its own)."""
        try:
            return self.fs.find(path, detail=detail)
        except (FileNotFoundError, NotADirectoryError):
            return {} if detail else []

    def glob(self, rel_dir: str, suffix: str) -> list[str]:
        """Store-relative paths of the files under ``rel_dir`` (recursively) ending in ``suffix``,
        sorted; temporary files are never listed."""
        base = self.path(rel_dir)
        out = []
        for p in self.find(base):
            name = posixpath.basename(p)
            if name.endswith(suffix) and not name.startswith(".tmp-"):
                out.append(posixpath.relpath(p, self.root))
        return sorted(out)

    def remove(self, rel: str) -> None:
        if self.exists(rel):
            self.fs.rm(self.path(rel), recursive=True)

    def check_writable(self) -> None:
        """Raise :class:`StoreError` naming the root when it cannot be written. Creates nothing:
        a local root that does not exist yet must have a writable nearest existing ancestor."""
        if self.is_local:
            path = self.root
            if os.path.exists(path) and not os.path.isdir(path):
                raise StoreError(f"dataset root {self.url} is a file, not a directory")
            probe = path
            while not os.path.exists(probe):
                if os.path.islink(probe):  # a dangling link: nothing could be created through it
                    raise StoreError(f"dataset root {self.url} is not writable: {probe} is a symbolic link to "
                                     f"{os.readlink(probe)}, which does not exist (create it, or point the link "
                                     "elsewhere)")
                probe = os.path.dirname(probe)
            if not os.path.isdir(probe):
                raise StoreError(f"dataset root {self.url} is not writable: {probe} is a file")
            if not os.access(probe, os.W_OK | os.X_OK):
                raise StoreError(f"dataset root {self.url} is not writable: no write permission on {probe}")
            # permissions do not tell everything (root may write anywhere by them; /proc, sysfs or a
            # read-only mount refuse anyway): make and remove a hidden directory where the root
            # would be created, so a root that cannot be made is refused before any work
            try:
                os.rmdir(tempfile.mkdtemp(prefix=".tmp-probe-", dir=probe))
            except OSError as exc:
                raise StoreError(f"dataset root {self.url} cannot be created: {probe} refuses new files "
                                 f"({exc.strerror or exc}); give a directory you can write, e.g. --root ./data") from None
            return
        fs, root = self.fs, self.root
        try:
            if fs.exists(root) and not fs.isdir(root):
                raise StoreError(f"dataset root {self.url} is a file, not a directory")
            probe = posixpath.join(root, f".tmp-probe-{uuid.uuid4().hex}")
            fs.pipe_file(probe, b"")
            fs.rm(probe)
        except StoreError:
            raise
        except Exception as exc:  # PermissionError, read-only fs, ...
            raise StoreError(f"dataset root {self.url} is not writable: {exc}") from None

    # -- layout -----------------------------------------------------------------------------
    @staticmethod
    def table_dir(table: str) -> str:
        try:
            return TABLE_DIRS[table]
        except KeyError:
            raise StoreError(f"unknown table {table!r} (tables: {', '.join(TABLE_DIRS)})") from None

    @staticmethod
    def asset_mesh_path(asset_id: str) -> str:
        return f"{ADMESH_MESHES}/{asset_id}.glb"

    @staticmethod
    def asset_texture_path(asset_id: str) -> str:
        return f"{ADMESH_TEXTURES}/{asset_id}.npz"

    @staticmethod
    def scene_mesh_path(stuff_asset_id: str) -> str:
        """Stuff meshes of a town, keyed ``<town>/<name>``."""
        return f"{SCENE_MESHES}/{stuff_asset_id}.glb"

    @staticmethod
    def occupancy_group(sequence_id: str, voxel_size_key: str) -> str:
        return f"{sequence_id}/{voxel_size_key}"

"""One writer at a time on a dataset root: the root lock, ``<root>/.carlaocc.lock``.

What must not interleave between two commands writing one root: an ingest's closing clean-up
(it lists the asset tables, then the mesh files, and removes the meshes no asset references: a
mesh another ingest wrote in between would go), lineage compaction (files merged and removed),
the run sequence numbers that order lineage (:meth:`carlaocc.catalog.lineage.LineageLog.new_run_id`),
and a stage's ``prepare`` (arrays re-created). So every command that writes a root -- ``run``
(any stages), ``ingest``, ``scenes swap`` -- holds the lock from planning to its last lineage
write. A second writer waits for it, saying once who holds it (``--no-wait`` refuses instead, exit
2, touching nothing). Two ``run``\\ s at once therefore run one after the other, and the second finds
the first one's work done: nothing is computed twice, nothing is lost.

Readers take no lock (``status``, ``catalog query``, ``export``, ``show``, the loader; ``verify``
takes it only to record the signatures it found, over records still the latest): every file appears whole under its final name (written aside, then renamed), and a
lineage listing that meets a file a compaction merged away lists again. What they read while a
writer works is a consistent file set, but possibly of a run half done: ``status`` says so.

Local roots (and NFSv4, where Linux maps ``flock`` onto POSIX byte-range locks the server keeps):
an exclusive ``flock`` on the lock file. The kernel releases it when the holding process ends,
however it ends (``kill -9``, a crash, a lost node's lease on NFS), so a lock is never left stale.
The empty file exists while a command holds the lock: its holder removes it when it lets go, and
one that waited on it checks, once it has it, that the file it locked is still the root's lock
file (else it opens the new one and waits again), so removing it races with no one. Nothing else
is written: a root at rest holds no lock file (a killed holder leaves an empty, unlocked one,
which the next holder removes), and a run with nothing to do leaves the root as it was. Another
user's lock file is opened read-only (``flock`` needs no write permission), so a root shared by
a group takes the lock whoever made the file. Who holds it is read from the kernel's
table of locks (``/proc/locks``: the holder's pid, then its command line), on this host; a holder
on another host (NFS) is "another process". A refusal on a root that did not exist removes the
folders it made too.

Object stores (``s3://``, ``gs://``...): no lock is taken. A lease by conditional writes (S3's
``If-None-Match``) would need each store's own API through fsspec, which does not expose it
uniformly; run one writing command at a time on an object-store root (readers are safe, as above).
``memory://`` roots live in one process, whose commands run one after another.
"""

from __future__ import annotations

import contextlib
import errno
import os
import socket
import threading
from datetime import datetime, timezone
from typing import Callable, Iterator

from carlaocc.catalog.store import Store, StoreError

__all__ = ["LOCK_FILE", "RootBusy", "holder", "root_lock"]

LOCK_FILE = ".carlaocc.lock"

# (lock file path, thread) -> [file descriptor, depth]: a thread that holds a root's lock may take
# it again (``ingest`` holds it around the engine run it starts, which takes it too); another
# thread of the process opens the file anew, and waits like another process
_HELD: dict[tuple[str, int], list[int]] = {}
_HELD_GUARD = threading.Lock()


class RootBusy(StoreError):
    """Another command holds the root lock and the caller would not wait."""


def _lock_path(store: Store) -> str:
    return os.path.join(store.root, LOCK_FILE)


def _lock_holder_pid(path: str) -> int | None:
    """The pid holding an ``flock`` on ``path`` according to ``/proc/locks`` (this host only)."""
    try:
        st = os.stat(path)
        with open("/proc/locks", encoding="ascii") as fh:
            lines = fh.read().splitlines()
    except OSError:
        return None
    # "1: FLOCK  ADVISORY  WRITE 2457 fd:01:1234567 0 EOF": device major:minor in hex, then inode
    want = (os.major(st.st_dev), os.minor(st.st_dev), st.st_ino)
    for line in lines:
        f = line.split()
        if len(f) < 6 or f[1] not in ("FLOCK", "POSIX") or "->" in f:  # NFS emulates flock with POSIX locks
            continue
        try:
            major, minor, ino = f[5].split(":")
            if (int(major, 16), int(minor, 16), int(ino)) == want:
                return int(f[4])
        except ValueError:
            continue
    return None


def _process_start(pid: int) -> datetime:
    """When a process of this host started: its start in clock ticks after boot
    (``/proc/<pid>/stat``, field 22, after the parenthesised command name) plus the boot time."""
    with open(f"/proc/{pid}/stat", encoding="ascii", errors="replace") as fh:
        ticks = int(fh.read().rsplit(")", 1)[1].split()[19])
    with open("/proc/stat", encoding="ascii") as fh:
        boot = next(int(line.split()[1]) for line in fh if line.startswith("btime "))
    return datetime.fromtimestamp(boot + ticks / os.sysconf("SC_CLK_TCK"), timezone.utc)


def holder(store: Store) -> str:
    """Who holds the root's lock, in words: ``pid 123 on host h (`carlaocc run ...`, since
    2026-11-28 04:10:05 UTC)``; ``another process`` when the kernel of this host does not know
    (a holder on another host of a shared disk)."""
    pid = _lock_holder_pid(_lock_path(store))
    if pid is None:
        return "another process (perhaps on another host)"
    try:
        with open(f"/proc/{pid}/cmdline", "rb") as fh:
            argv = [a.decode(errors="replace") for a in fh.read().split(b"\0") if a]
        # `python .../bin/carlaocc run ...` reads as `carlaocc run ...`
        while len(argv) > 1 and os.path.basename(argv[0]).startswith("python"):
            argv = argv[1:]
        command = " ".join(" ".join([os.path.basename(argv[0])] + argv[1:]).split())[:200] if argv else "?"
        since = _process_start(pid)
        return f"pid {pid} on {socket.gethostname()} (`{command}`, since {since:%Y-%m-%d %H:%M:%S} UTC)"
    except (OSError, ValueError, IndexError, StopIteration):
        return f"pid {pid} on {socket.gethostname()}"


def _missing_dirs(path: str) -> list[str]:
    """``path`` and those of its ancestors that do not exist, deepest first."""
    out = []
    while not os.path.exists(path):
        out.append(path)
        parent = os.path.dirname(path)
        if parent == path:
            break
        path = parent
    return out


@contextlib.contextmanager
def root_lock(store: Store, wait: bool = True, on_wait: Callable[[str], None] = lambda s: None) -> Iterator[None]:
    """Hold the root's writer lock for the ``with`` block (see the module docstring).

    ``wait``: block until the holder releases it (``on_wait`` is told once, with who holds it), or
    raise :class:`RootBusy` at once naming the holder. A root that cannot hold a lock file (a
    read-only disk) raises :class:`StoreError` naming the file. Object-store and ``memory://``
    roots take no lock. Reentrant within a thread."""
    if not store.is_local:
        yield
        return
    path = _lock_path(store)
    me = (path, threading.get_ident())
    with _HELD_GUARD:
        held = _HELD.get(me)
        if held is not None:
            held[1] += 1
    if held is not None:
        try:
            yield
        finally:
            with _HELD_GUARD:
                held[1] -= 1
        return
    import fcntl

    made = _missing_dirs(store.root)  # removed again when the command leaves nothing in them
    told, spins = False, 0
    while True:
        try:
            os.makedirs(store.root, exist_ok=True)
            try:
                fd = os.open(path, os.O_RDWR | os.O_CREAT | os.O_EXCL | os.O_CLOEXEC, 0o666)
            except FileExistsError:
                try:
                    fd = os.open(path, os.O_RDWR | os.O_CLOEXEC)
                except PermissionError:  # another user's lock file (umask 022): flock needs no write
                    fd = os.open(path, os.O_RDONLY | os.O_CLOEXEC)
        except FileNotFoundError:
            # removed between the two opens by the holder letting go: again (a dangling symbolic
            # link named like the lock file would do this for ever: refused after a few turns)
            spins += 1
            if spins > 100:
                raise StoreError(f"cannot take the root lock {path}: it cannot be created nor opened (a dangling "
                                 "symbolic link?); remove it") from None
            continue
        except OSError as exc:
            raise StoreError(f"cannot take the root lock {path}: {exc.strerror or exc} (a root is written by one "
                             "command at a time; its lock file must be writable)") from None
        try:
            try:
                fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
            except OSError as exc:
                if exc.errno not in (errno.EWOULDBLOCK, errno.EAGAIN, errno.EACCES):
                    raise StoreError(f"cannot take the root lock {path}: {exc.strerror or exc}") from None
                who = holder(store)
                if not wait:
                    raise RootBusy(f"dataset root {store.url} is being written by {who}; wait for it to finish, "
                                   "or run without --no-wait to wait for it") from None
                if not told:
                    on_wait(f"waiting for the dataset root {store.url}: it is being written by {who} "
                            "(one writer at a time; Ctrl-C stops waiting)")
                    told = True
                fcntl.flock(fd, fcntl.LOCK_EX)  # interrupted by a signal: its exception propagates
            # the file locked must still be the root's lock file: a refusal on a fresh root removes
            # it (and the root) on its way out, while this process waited on it
            try:
                current = os.stat(path)
            except FileNotFoundError:
                current = None
            if current is not None and os.path.samestat(current, os.fstat(fd)):
                break
        except BaseException:
            os.close(fd)
            raise
        os.close(fd)
    try:
        with _HELD_GUARD:
            _HELD[me] = [fd, 1]
        try:
            yield
        finally:
            with _HELD_GUARD:
                del _HELD[me]
    finally:
        # the lock file goes with the lock (whoever waits on it opens it anew: see above; one left
        # by a killed holder or a refused maker goes with the next holder's), and so
        # does a root this command made and wrote nothing into (a refusal): no trace is left
        with contextlib.suppress(OSError):
            os.unlink(path)  # the current lock file (checked when taken): only its holder removes it
            if made and not os.listdir(store.root):
                for d in made:
                    os.rmdir(d)
        os.close(fd)  # closing the descriptor releases the flock

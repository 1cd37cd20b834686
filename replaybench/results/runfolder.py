"""A run folder's life cycle: checked, locked, written beside it and swapped in whole.

``replaybench run --out OUT`` (and ``peak``) never writes into OUT itself. ``RunFolder``:

1. checks OUT before anything is created (``check_out_dir``): not a symbolic link, not a file,
   its nearest existing parent a writable folder; a non-empty OUT only with ``force``, and only
   when it is a run folder (it holds run.json, or peak.json for ``peak``);
2. creates OUT's missing parents and locks ``.<name>.lock`` beside OUT (``fcntl.flock``): a
   second run on the same OUT is refused at once; the kernel releases the lock when the process
   ends, however it ends;
3. cleans up after a killed run: ``.<name>.tmp-<pid>`` folders whose process is gone are removed;
   ``.<name>.old-<pid>`` (a previous run set aside by a swap that was cut short between its two
   renames) is renamed back to OUT when OUT is missing, and removed otherwise;
4. gives the run ``.<name>.tmp-<pid>`` to write into (``path``);
5. ``commit()``: renames OUT, if there is one, to ``.<name>.old-<pid>``, the temporary folder to
   OUT, and removes the old one (Ctrl-C and SIGTERM are held back during the two renames).
   Leaving the ``with`` block without a commit removes the temporary folder and the parents it
   created: OUT is untouched.
"""

from __future__ import annotations

import contextlib
import os
import re
import shutil
from pathlib import Path
from typing import TYPE_CHECKING

from replaybench.errors import OutputError, UsageError

if TYPE_CHECKING:
    from types import TracebackType
    from typing import Self

try:
    import fcntl
except ImportError:  # pragma: no cover - not POSIX: no lock
    fcntl = None  # type: ignore[assignment]

__all__ = ['OUTPUTS_MCAP', 'RunFolder', 'check_out_dir', 'with_filename']

#: The run folder's MCAP: every backend's outputs, whatever its task (run.json
#: ``outputs.outputs_mcap``; detections.mcap in a run folder of run.json schema_version 1).
OUTPUTS_MCAP = 'outputs.mcap'


def with_filename(err: OSError, path: str | Path) -> OSError:
    """``err`` naming ``path`` when it names no file (a failed ``write`` names none)."""
    if err.filename is not None:
        return err
    return OSError(err.errno, err.strerror or str(err), str(path))


def _absolute(path: Path) -> Path:
    return Path(os.path.abspath(path))  # noqa: PTH100 - lexical: OUT itself, not a link target


def check_out_dir(out: Path, *, force: bool, marker: str = 'run.json', kind: str = 'run') -> None:
    """Refuse an output folder that cannot be (re)placed; reads only, creates nothing.

    ``marker`` is the file that makes a folder a ``kind`` folder, which ``force`` may replace.
    """
    out = Path(out)
    if not _absolute(out).name:
        msg = f'--out {out} names no folder'
        raise UsageError(msg)
    if out.is_symlink():
        target = out.readlink()
        if not out.exists():
            msg = (
                f'--out {out} is a dangling symbolic link (to {target}): remove it or choose '
                'another --out'
            )
            raise UsageError(msg)
        msg = f'--out {out} is a symbolic link (to {target}): give the folder itself'
        raise UsageError(msg)
    if out.exists():
        if not out.is_dir():
            msg = f'{out} exists and is not a directory'
            raise UsageError(msg)
        try:
            empty = not any(out.iterdir())
        except OSError as err:
            msg = f'cannot read {out}: {err.strerror or err}'
            raise UsageError(msg) from err
        if not empty and not force:
            msg = f'output folder {out} is not empty: choose another --out or pass --force'
            raise UsageError(msg)
        if not empty and not (out / marker).is_file():
            msg = (
                f'{out} is not a {kind} folder (no {marker}): --force replaces only a {kind} '
                'folder; choose another --out'
            )
            raise UsageError(msg)
        _check_writable(_absolute(out).parent, out)
        return
    ancestor = _absolute(out).parent
    while not ancestor.exists():
        if ancestor.is_symlink():
            msg = f'cannot create {out}: {ancestor} is a dangling symbolic link'
            raise UsageError(msg)
        ancestor = ancestor.parent
    if not ancestor.is_dir():
        msg = f'cannot create {out}: {ancestor} is not a directory'
        raise UsageError(msg)
    _check_writable(ancestor, out)


def _check_writable(folder: Path, out: Path) -> None:
    if not os.access(folder, os.W_OK | os.X_OK):
        msg = f'cannot write {out}: {folder} is not writable'
        raise UsageError(msg)


def _alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except OSError:  # EPERM: someone else's process
        return True
    return True


def _fsync_dir(folder: Path) -> None:
    with contextlib.suppress(OSError):
        fd = os.open(folder, os.O_RDONLY)
        try:
            os.fsync(fd)
        finally:
            os.close(fd)


class RunFolder:
    """OUT, written as a temporary sibling and swapped in whole by ``commit``.

    Use as a context manager: entering checks OUT, locks it and creates the temporary folder
    (``path``); leaving without ``commit`` removes it; leaving always releases the lock.
    """

    def __init__(
        self, out: Path, *, force: bool, marker: str = 'run.json', kind: str = 'run'
    ) -> None:
        self.out = Path(out)
        self.force = force
        self.marker = marker
        self.kind = kind
        self._target = _absolute(self.out)
        self.parent = self._target.parent
        self._name = self._target.name
        self.path = self.parent / f'.{self._name}.tmp-{os.getpid()}'
        self._lock_path = self.parent / f'.{self._name}.lock'
        self._lock_fd: int | None = None
        self._created: list[Path] = []
        self.committed = False

    # -- entering ---------------------------------------------------------------------------

    def __enter__(self) -> Self:
        self._check()
        self._make_parents()
        try:
            self._lock()
            self._clean_leftovers()
            self._check()  # again, under the lock: a put-back or another run may have changed OUT
            shutil.rmtree(self.path, ignore_errors=True)
            try:
                self.path.mkdir()
            except OSError as err:
                raise self.output_error(err) from err
        except BaseException:
            self._release()
            raise
        return self

    def _check(self) -> None:
        check_out_dir(self.out, force=self.force, marker=self.marker, kind=self.kind)

    def _make_parents(self) -> None:
        missing: list[Path] = []
        folder = self.parent
        while not folder.exists():
            missing.append(folder)
            folder = folder.parent
        for folder in reversed(missing):
            try:
                folder.mkdir()
            except FileExistsError:
                continue
            except OSError as err:
                self._remove_created()
                msg = f'cannot create {folder}: {err.strerror or err}'
                raise UsageError(msg) from err
            self._created.append(folder)

    def _lock(self) -> None:
        if fcntl is None:  # pragma: no cover
            return
        for _ in range(8):
            try:
                fd = os.open(self._lock_path, os.O_RDWR | os.O_CREAT, 0o644)
            except OSError as err:
                msg = f'cannot lock {self.out}: {self._lock_path}: {err.strerror or err}'
                raise UsageError(msg) from err
            try:
                fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
            except BlockingIOError as err:
                holder = _read_pid(fd)
                os.close(fd)
                by = f' (pid {holder})' if holder else ''
                msg = (
                    f'{self.out} is in use by another replaybench run{by}: wait for it to end '
                    'or choose another --out'
                )
                raise UsageError(msg) from err
            # the run before us may have removed the file between our open and our lock
            try:
                same = os.path.samestat(os.fstat(fd), self._lock_path.stat())
            except FileNotFoundError:
                same = False
            if same:
                with contextlib.suppress(OSError):
                    os.ftruncate(fd, 0)
                    os.pwrite(fd, f'{os.getpid()}\n'.encode(), 0)
                self._lock_fd = fd
                return
            os.close(fd)
        msg = f'{self.out} is in use by other replaybench runs: try again'
        raise UsageError(msg)

    def _clean_leftovers(self) -> None:
        pattern = re.compile(rf'\.{re.escape(self._name)}\.(tmp|old)-([0-9]+)\Z')
        with os.scandir(self.parent) as entries:
            found = [(m, Path(e.path)) for e in entries if (m := pattern.match(e.name))]
        for match, path in sorted(found, key=lambda item: item[1].name):
            pid = int(match.group(2))
            if pid != os.getpid() and _alive(pid):
                continue
            if match.group(1) == 'old' and not os.path.lexists(self._target):
                with contextlib.suppress(OSError):
                    path.rename(self._target)  # the previous run, put back
                    continue
            shutil.rmtree(path, ignore_errors=True)

    # -- leaving ----------------------------------------------------------------------------

    def commit(self) -> None:
        """Put the temporary folder in OUT's place; OUT's previous content is removed."""
        old: Path | None = None
        # No signal handler is installed here (a library call leaves them alone): whatever
        # stops the swap between its two renames (an error, Ctrl-C's KeyboardInterrupt) puts the
        # previous run back; a kill -9 there leaves it as .NAME.old-PID, which the next run on
        # OUT puts back (``_clean_leftovers``).
        try:
            if os.path.lexists(self._target):
                old = self.parent / f'.{self._name}.old-{os.getpid()}'
                shutil.rmtree(old, ignore_errors=True)
                self._target.rename(old)
            try:
                self.path.rename(self._target)
            except BaseException:
                if old is not None:
                    old.rename(self._target)
                raise
            self.committed = True
        except OSError as err:
            msg = f'cannot move the run into {self.out}: {err.strerror or err}'
            raise OutputError(msg) from err
        _fsync_dir(self.parent)
        if old is not None:
            shutil.rmtree(old, ignore_errors=True)

    def __exit__(
        self,
        exc_type: type[BaseException] | None,
        exc: BaseException | None,
        tb: TracebackType | None,
    ) -> None:
        try:
            if not self.committed:
                shutil.rmtree(self.path, ignore_errors=True)
        finally:
            self._release()
            if not self.committed:
                self._remove_created()

    def _release(self) -> None:
        fd, self._lock_fd = self._lock_fd, None
        if fd is None:
            return
        with contextlib.suppress(OSError):
            self._lock_path.unlink()  # still held: nobody takes a lock on it in between
        os.close(fd)

    def _remove_created(self) -> None:
        for folder in reversed(self._created):
            with contextlib.suppress(OSError):
                folder.rmdir()
        self._created = []

    # -- errors -----------------------------------------------------------------------------

    def display(self, path: str | Path) -> Path:
        """``path`` inside the temporary folder as it would be named inside OUT."""
        path = _absolute(Path(path))
        if path.is_relative_to(self.path):
            return self.out / path.relative_to(self.path)
        return path

    def output_error(self, err: OSError) -> OutputError:
        """One line for a failed write: the first file that failed, named as inside OUT."""
        first: OSError = err
        cause: BaseException | None = err
        while cause is not None:  # what failed first; what followed failed because of it
            if isinstance(cause, OSError) and cause.filename is not None:
                first = cause
            cause = cause.__context__
        if first.filename is None:
            return OutputError(f'cannot write {self.out}: {first.strerror or first}')
        name = self.display(first.filename)
        if not name.is_relative_to(self.out):  # not one of the run's files
            return OutputError(f'{name}: {first.strerror or first}')
        return OutputError(f'cannot write {name}: {first.strerror or first}')


def _read_pid(fd: int) -> int | None:
    try:
        text = os.pread(fd, 32, 0).decode('ascii', 'replace').strip()
    except OSError:
        return None
    return int(text) if text.isdigit() else None

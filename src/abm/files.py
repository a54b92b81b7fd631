"""Reading and writing files safely: loaders that never run code, atomic writes, one writer per folder.

Every file abm reads is data: checkpoints go through :func:`load_torch_data` (``torch.load`` with
``weights_only=True``), YAML through :func:`load_yaml` (a safe loader that refuses duplicate keys), ``.npz`` through
``np.load(allow_pickle=False)`` and HDF5 through h5py (which never unpickles).

Writes go through :func:`atomic_path` (a temporary file renamed into place, removed on any failure, a
full disk included) and commands that write a run folder hold its :class:`FolderLock`.
"""

from __future__ import annotations

import errno
import hashlib
import logging
import os
import pickle
import re
import socket
from collections.abc import Iterable, Iterator, Sequence
from contextlib import contextmanager
from pathlib import Path
from typing import Any

from abm.errors import ConfigError, DataError, OutputError


def load_torch_data(path: str | Path, what: str, allowed_globals: Sequence[Any] = (),
                    map_location: Any = "cpu") -> Any:
    """``torch.load(path, weights_only=True)``: tensors and plain data only, so a crafted file cannot run code.

    The file's bytes are checked first (:func:`check_torch_archive`): a changed byte is refused before
    ``torch.load`` reads it, which itself would load most damaged tensors without a word.

    Args:
        what: what the file should be, for the messages (``"abm policy checkpoint"``).
        allowed_globals: extra classes the file may hold (``torch.serialization.safe_globals``).

    Raises:
        ValueError: the file holds other Python objects (``refusing to load ...``), is damaged (its bytes do not
            match the checksums in it) or cannot be read.
    """
    import torch

    check_torch_archive(path, what)
    try:
        with torch.serialization.safe_globals(list(allowed_globals)):
            return torch.load(path, map_location=map_location, weights_only=True)
    except pickle.UnpicklingError as err:
        found = re.search(r"GLOBAL ([\w.]+)", str(err))
        if found:
            raise DataError(
                f"refusing to load {path}: it holds Python objects other than tensors and plain data (it names the "
                f"Python object {found.group(1)}), which an {what} never does (it may be crafted to run code); abm "
                "never loads such a file: use one written by abm (abm train, abm export, abm clip train)") from None
        raise DataError(
            f"refusing to load {path}: it is not the plain data torch.save writes ({_refused_object(err)}); the file "
            f"is damaged, not an {what}, or crafted to run code: use one written by abm (abm train, abm export, abm "
            "clip train)") from None
    except Exception as err:  # noqa: BLE001 - any other reading failure means a corrupt file
        raise DataError(f"cannot read {what} {path}: {_without_torch_hints(str(err))}; the file is damaged or not "
                        f"an {what}") from None


_TORCH_HINT = re.compile(r"weights_only|safe_globals|add_safe_globals|trusted source|torch\.load|documentation|"
                         r"file an issue", re.IGNORECASE)


def _refused_object(err: BaseException) -> str:
    """What torch's weights-only unpickler refused, in abm's words (never torch's advice to retry with
    weights-only loading turned off, which would run the file's code)."""
    text = str(err)
    found = re.search(r"Unsupported operand (\d+)", text)
    if found:
        return f"pickle operation {found.group(1)}, which plain data never uses"
    return _without_torch_hints(text) or "data torch's weights-only reader refuses"


def _without_torch_hints(text: str) -> str:
    """The lines of a torch error that state the problem, without its hints (retry with weights-only loading
    turned off, allow-list a class, read the documentation)."""
    lines = [line.strip() for line in text.splitlines() if line.strip()]
    kept = [line for line in lines if not _TORCH_HINT.search(line)]
    return " ".join(kept)[:300]


SEAL_PREFIX = b"abm-sha256:"
_EOCD = b"PK\x05\x06"  # end of a zip file's central directory: 22 bytes, then the archive comment
_SEAL = re.compile(re.escape(SEAL_PREFIX) + rb"[0-9a-f]{64}")


def seal_torch_archive(path: str | Path) -> None:
    """Record the sha256 of a file ``torch.save`` just wrote in the file itself (its zip archive comment), so
    :func:`check_torch_archive` refuses any changed byte. ``torch.load`` reads the sealed file as before."""
    path = Path(path)
    with path.open("r+b") as f:
        size = f.seek(0, os.SEEK_END)
        f.seek(max(0, size - 22))
        tail = f.read(22)
        if len(tail) != 22 or not tail.startswith(_EOCD) or tail[20:22] != b"\0\0":
            raise ValueError(f"{path} is not a zip archive without a comment (torch.save's format); cannot seal it")
        f.seek(0)
        digest = hashlib.sha256()
        while block := f.read(1 << 20):
            digest.update(block)
        comment = SEAL_PREFIX + digest.hexdigest().encode()
        f.seek(size - 2)
        f.write(len(comment).to_bytes(2, "little") + comment)


def check_torch_archive(path: str | Path, what: str = "file") -> bool:
    """Check the bytes of a file written by ``torch.save`` before it is loaded.

    A file sealed by :func:`seal_torch_archive` (every checkpoint abm writes) must match the sha256 it holds,
    which covers every byte. Another zip archive (older checkpoints, the committed model zoo) must match the
    CRC-32 of every member (``zipfile.ZipFile.testzip``), which covers every byte of its contents. A file in
    torch's legacy format (not a zip) has no checksums.

    Returns:
        ``True`` when every byte was checked (a sealed file), ``False`` otherwise.

    Raises:
        ValueError: naming the file, when a check fails.
    """
    import zipfile

    path = Path(path)
    damaged = ("the file was changed or damaged after it was written (a partial copy or download, a bad disk): "
               "restore it from where it came from, or write it again (abm train, abm export)")
    try:
        with path.open("rb") as f:
            head = f.read(4)
            size = f.seek(0, os.SEEK_END)
            f.seek(max(0, size - (22 + 65535)))
            tail = f.read()
    except OSError as err:
        raise DataError(f"cannot read {what} {path}: {err.strerror or err}") from None
    if not head.startswith(b"PK") and not zipfile.is_zipfile(path):
        return False  # torch's legacy (pickle) format: no checksums; torch.load checks what it can
    end = tail.rfind(_EOCD)
    comment = tail[end + 22:] if end >= 0 else b""
    if end < 0 or int.from_bytes(tail[end + 20:end + 22], "little") != len(comment):
        raise DataError(f"{path}: the end of its zip archive is damaged; {damaged}")
    if comment:
        if not _SEAL.fullmatch(comment):
            raise DataError(f"{path}: its zip archive comment is not abm's sha256 record; {damaged}")
        body = size - len(tail) + end + 20  # every byte before the comment's length, which was 0 when sealed
        digest = hashlib.sha256()
        with path.open("rb") as f:
            remaining = body
            while remaining and (block := f.read(min(1 << 20, remaining))):
                digest.update(block)
                remaining -= len(block)
        digest.update(b"\0\0")
        if digest.hexdigest().encode() != comment[len(SEAL_PREFIX):]:
            raise DataError(f"{path} does not match the sha256 recorded in it when it was written; {damaged}")
        return True
    try:
        with zipfile.ZipFile(path) as archive:
            bad = archive.testzip()
    except (zipfile.BadZipFile, OSError, EOFError, ValueError, NotImplementedError) as err:
        raise DataError(f"{path}: its zip archive cannot be read ({err}); {damaged}") from None
    if bad is not None:
        raise DataError(f"{path}: {bad} inside it does not match its CRC-32; {damaged}")
    return False


class DuplicateKeyError(ConfigError):
    """A YAML mapping names one key twice (YAML itself would keep the last value without a word)."""


class _Duplicate(Exception):  # noqa: N818 - internal signal: (key, first line, second line), 1-based
    pass


def _strict_loader(text: str) -> Any:
    """A ``yaml.SafeLoader`` (plain data only) over ``text`` that refuses a mapping naming a key twice."""
    import yaml

    class StrictSafeLoader(yaml.SafeLoader):  # type: ignore[misc]  # PyYAML has no type information here
        def construct_mapping(self, node: Any, deep: bool = False) -> Any:  # noqa: FBT001, FBT002 - PyYAML's
            if isinstance(node, yaml.MappingNode):
                seen: dict[Any, int] = {}
                for key_node, _ in node.value:
                    if key_node.tag == "tag:yaml.org,2002:merge":  # ``<<: *base`` overrides on purpose
                        continue
                    key = self.construct_object(key_node, deep=True)
                    line = key_node.start_mark.line + 1
                    try:
                        if key in seen:
                            raise _Duplicate(key, seen[key], line)
                        seen[key] = line
                    except TypeError:  # an unhashable key: PyYAML's own error below names it
                        continue
            return super().construct_mapping(node, deep=deep)

    return StrictSafeLoader(text)


def parse_yaml(text: str, source: str | Path, what: str) -> Any:
    """Safe-load YAML ``text`` as plain data, refusing duplicate keys (``source`` names it in the messages).

    Raises:
        DuplicateKeyError: (a ``ValueError``) a mapping names a key twice: the message names ``source``, the
            key and both line numbers.
        ValueError: naming ``source``, when the text is not valid (safe) YAML.
    """
    import yaml

    loader = None
    try:
        loader = _strict_loader(text)  # its reader already refuses non-printable characters
        return loader.get_single_data()
    except _Duplicate as err:
        key, first, again = err.args
        raise DuplicateKeyError(
            f"{source}: the key {key!r} appears twice in one section of the {what} (lines {first} and {again}); "
            "YAML would silently keep only the last one: remove or merge one of them") from None
    except yaml.YAMLError as err:
        problem, fix = _yaml_problem(err)
        raise ConfigError(f"{source}: not a valid {what} (YAML error{problem}); {fix}") from None
    finally:
        if loader is not None:
            loader.dispose()


def _yaml_problem(err: Exception) -> tuple[str, str]:
    """``(where and what is wrong, the fix)`` of a PyYAML error, in the file's terms (PyYAML names the text
    ``<unicode string>`` and a tag by its long form)."""
    import yaml

    mark = getattr(err, "problem_mark", None) or getattr(err, "context_mark", None)
    where = f" at line {mark.line + 1}, column {mark.column + 1}" if mark is not None else ""
    problem = " ".join(str(getattr(err, "problem", None) or err).split())
    tag = re.search(r"constructor for the tag '([^']+)'", problem)
    if isinstance(err, yaml.constructor.ConstructorError) and tag:
        name = tag.group(1).replace("tag:yaml.org,2002:", "!!")
        if name.startswith("!!python"):
            return (f"{where}: the tag {name} would build a Python object",
                    "remove the tag (abm reads plain data only and never builds objects from a file)")
        return f"{where}: unknown tag {name}", "remove the tag"
    context = " ".join(str(getattr(err, "context", None) or "").split())
    return f"{where}: {problem}{f', {context}' if context else ''}", "fix the YAML there"


def load_yaml(path: str | Path, what: str) -> Any:
    """Read a YAML file as plain data (a ``!!python/...`` tag is refused, never run; :func:`parse_yaml`).

    Every YAML file abm reads goes through here (robot, calibration, split, template and recipe files), so a
    key given twice (two ``limits:`` sections) is an error naming the file, the key and its lines, never a
    silent choice of the last one.

    Raises:
        ValueError: naming the file, when it is missing, unreadable, not valid (safe) YAML, or names a key twice.
    """
    path = Path(path)
    try:
        text = path.read_text(encoding="utf-8")
    except FileNotFoundError:
        raise ConfigError(f"{path}: {what} not found") from None
    except (OSError, UnicodeDecodeError) as err:
        raise ConfigError(f"{path}: cannot read the {what} ({err})") from None
    return parse_yaml(text, path, what)


class WriteError(OutputError):
    """A file could not be written (full disk, a parent that is a file, no permission); nothing was left."""


# errno values that are the user's to fix (a path, the disk), reported as one line by the command line
USER_ERRNOS = frozenset({errno.ENOSPC, errno.EDQUOT, errno.EFBIG, errno.EACCES, errno.EPERM, errno.EROFS,
                         errno.ENOTDIR, errno.EISDIR, errno.EEXIST, errno.ENAMETOOLONG})


def write_error(path: Path | str, err: OSError, verb: str = "write") -> WriteError:
    """One line naming ``path``, the reason and the fix, for an ``OSError`` writing (or using) it."""
    code = err.errno
    if code is None:  # h5py and others put the errno in the text only
        found = re.search(r"errno = (\d+)", str(err))
        code = int(found.group(1)) if found else None
    reason = os.strerror(code) if code else (str(err).strip().splitlines() or ["write failed"])[0]
    hint = {errno.ENOSPC: "free some disk space and run the command again",
            errno.EDQUOT: "free some disk space and run the command again",
            errno.EFBIG: "the file size limit of this process was reached (ulimit -f)",
            errno.EACCES: "choose a folder you may write to",
            errno.EROFS: "choose a folder on a writable disk",
            errno.ENOTDIR: "a parent of it is a file, not a folder: choose another path",
            errno.EEXIST: "a parent of it is a file, not a folder: choose another path",
            errno.EISDIR: "it is a folder: give a file path"}.get(code, "") if code is not None else ""
    return WriteError(f"cannot {verb} {path}: {reason}" + (f"; {hint}" if hint else ""))


@contextmanager
def atomic_path(path: str | Path) -> Iterator[Path]:
    """A temporary path next to ``path`` to write, renamed over ``path`` when the block succeeds.

    A failure (a full disk, an interruption) leaves ``path`` as it was and removes the temporary file;
    an ``OSError`` becomes a one-line :class:`WriteError` naming ``path`` and the fix.
    """
    path = Path(path)
    tmp = path.with_name(f".{path.name}.tmp{os.getpid()}")
    try:
        if path.is_dir():
            raise IsADirectoryError(errno.EISDIR, "it is a folder; give a file path", str(path))
        path.parent.mkdir(parents=True, exist_ok=True)
        if tmp.is_symlink():  # a link planted at the temporary name would send the write elsewhere
            tmp.unlink()
        yield tmp
        os.replace(tmp, path)
    except BaseException as err:
        _remove_quietly(tmp)
        cause = _os_error_in(err)
        if cause is not None:
            raise write_error(path, cause) from None
        raise


def _os_error_in(err: BaseException | None) -> OSError | None:
    """The ``OSError`` behind ``err`` (libraries such as torch re-raise a failed write as another error)."""
    for _ in range(8):
        if err is None or isinstance(err, OSError):
            return err
        err = err.__cause__ or err.__context__
    return None


def _remove_quietly(path: Path) -> None:
    try:
        path.unlink(missing_ok=True)
    except OSError:
        pass


def write_text_atomic(path: str | Path, text: str) -> Path:
    """Write ``text`` (UTF-8) to ``path`` atomically (:func:`atomic_path`)."""
    with atomic_path(path) as tmp:
        tmp.write_text(text, encoding="utf-8")
    return Path(path)


LOCK_NAME = ".abm.lock"


class FolderBusyError(OutputError):
    """Another live process writes into the folder."""


class LinkError(WriteError):
    """A path abm would write or delete is a symbolic link: abm never writes or deletes through one."""


def refuse_links(folder: str | Path, names: Iterable[str], fix: str = "remove the link") -> None:
    """Raise :class:`LinkError` if ``FOLDER/NAME`` is a symbolic link for any of ``names``.

    A command that owns a folder (a run folder, a dataset) writes its own files there; a link in their place
    would make it write (or truncate, or delete) whatever the link points to, outside what the user named.

    Args:
        names: entries of ``folder`` (relative paths; a ``*`` pattern checks every match, e.g. ``checkpoints/*``).
        fix: the end of the message (what the user should do).
    """
    folder = Path(folder)
    for name in names:
        paths = folder.glob(name) if any(c in name for c in "*?[") else [folder / name]
        for path in paths:
            if path.is_symlink():
                raise LinkError(f"{path} is a symbolic link (to {os.readlink(path)}); abm never writes through a "
                                f"link in a folder it owns: {fix}")


def is_inside(path: str | Path, root: str | Path) -> bool:
    """Whether ``path`` stays inside ``root`` once both are resolved (``..`` and symbolic links followed)."""
    return Path(path).resolve().is_relative_to(Path(root).resolve())


class FolderLock:
    """One writer per folder: an exclusive ``flock`` on ``FOLDER/.abm.lock``, which holds the owner's pid.

    The kernel releases the lock when its owner dies, so a lock file left by a killed process is stale:
    the next command takes it over (and says so). Use as a context manager::

        with FolderLock(run, "abm train"):
            ...

    Raises:
        FolderBusyError: a live process holds the lock (the message names its pid and command).
    """

    def __init__(self, folder: str | Path, command: str) -> None:
        self.folder = Path(folder)
        self.command = command
        self.path = self.folder / LOCK_NAME
        self._fd: int | None = None
        self._created_folder = False

    def __enter__(self) -> FolderLock:
        import fcntl

        if self.folder.exists() and not self.folder.is_dir():
            raise WriteError(f"{self.folder} is a file; give a folder")
        self._created_folder = not self.folder.exists()
        try:
            self.folder.mkdir(parents=True, exist_ok=True)
        except OSError as err:
            raise write_error(self.folder, err) from None
        while True:
            try:  # O_NOFOLLOW: a link in the lock file's place would have its target truncated and written
                fd = os.open(self.path, os.O_RDWR | os.O_CREAT | os.O_NOFOLLOW, 0o644)
            except OSError as err:
                self._remove_created_folder()
                if err.errno == errno.ELOOP or self.path.is_symlink():
                    raise LinkError(f"{self.path} is a symbolic link (to {os.readlink(self.path)}); abm never "
                                    f"writes through a link in a folder it owns: remove the link and run "
                                    f"{self.command} again") from None
                raise write_error(self.path, err) from None
            try:
                fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
            except BlockingIOError:
                owner = os.read(fd, 200).decode("utf-8", "replace").strip() or "another process"
                os.close(fd)
                self._remove_created_folder()
                raise FolderBusyError(f"{self.folder} is in use by {owner}: one command at a time writes a run "
                                      f"folder; wait for it to finish (or stop it), or use another folder") from None
            try:  # the file may have been removed by its last owner between our open and flock: retry
                same = os.fstat(fd).st_ino == os.stat(self.path).st_ino
            except FileNotFoundError:
                same = False
            if same:
                break
            os.close(fd)
        previous = os.read(fd, 200).decode("utf-8", "replace").strip()
        if previous:
            logging.getLogger("abm").info("%s: taking over the stale lock of %s (no longer running)", self.folder,
                                          previous)
        os.ftruncate(fd, 0)
        os.pwrite(fd, f"{self.command} (pid {os.getpid()} on {socket.gethostname()})\n".encode(), 0)
        self._fd = fd
        return self

    def __exit__(self, *exc: object) -> None:
        if self._fd is not None:
            _remove_quietly(self.path)  # while still holding it, so nobody locks a file being removed
            os.close(self._fd)
            self._fd = None
            self._remove_created_folder()

    def _remove_created_folder(self) -> None:
        if self._created_folder:
            try:
                self.folder.rmdir()  # only when still empty: the command wrote nothing
            except OSError:
                pass


def sha256_file(path: str | Path) -> str:
    """Hex sha256 of a file's bytes, read in 1 MiB blocks."""
    h = hashlib.sha256()
    with Path(path).open("rb") as f:
        while block := f.read(1 << 20):
            h.update(block)
    return h.hexdigest()

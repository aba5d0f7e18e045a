"""Files written whole or not at all.

Every file the library writes for a user or for a later task goes through :func:`replacing`:
the bytes go to a temporary file beside the destination, with a name no other writer shares,
created exclusively; it is flushed and synced to the disk, then renamed onto the destination,
and the folder is synced so that the rename survives a crash. A reader sees the old file or the
new one, never a part. Two writers of one file (a task run again while the worker thought lost
still runs, two hosts sharing a folder) each write their own temporary, and the last rename wins
with a whole file; with ``overwrite=False`` the first wins and the others are refused.

Files that a library writes by name (LAS, Zarr stores) are written under :func:`temporary`,
then :func:`sync` and :func:`replace` do the same for them, folders included.

A writer killed before the rename leaves its temporary, a hidden ``.NAME.TOKEN.partial.SUFFIX``
beside the destination, and the destination as it was. Nothing reads or reuses a temporary
(every write takes a new random name, and a no-clobber write looks at the destination's name
only), so a leftover never blocks a later write nor passes for output; it is not removed
automatically, since a temporary that looks old may be another host's write still under way.
"""
import contextlib
import ctypes
import errno
import functools
import os
import secrets
import shutil
import stat
import sys
from pathlib import Path

# renameat2(2) flags (Linux 3.15 and later, glibc 2.28 and later).
_RENAME_NOREPLACE = 1
_RENAME_EXCHANGE = 2
_AT_FDCWD = -100


def check_folder(path):
    """Refuse (``PermissionError`` or ``OSError`` naming it) the folder of ``path`` where a
    temporary cannot be created in it: before the work that ends in :func:`replacing`, not
    after. A file of the same kind is created there and removed."""
    folder = Path(path).parent
    probe = temporary(path)
    try:
        fd = os.open(probe, os.O_CREAT | os.O_EXCL | os.O_WRONLY, 0o600)
    except OSError as exc:
        raise type(exc)(exc.errno, f"output folder {folder} is not writable "
                                   f"({exc.strerror or exc})") from None
    os.close(fd)
    os.unlink(probe)


def temporary(path):
    """A name beside ``path`` that no other writer takes: hidden, with a random token, and
    ending in ``path``'s own suffix (writers that choose their format by the suffix keep
    it)."""
    path = Path(path)
    return path.with_name(f".{path.stem}.{secrets.token_hex(8)}.partial{path.suffix}")


@contextlib.contextmanager
def replacing(path, *, overwrite=True, exists_message=None):
    """Write ``path`` atomically: ``with replacing(path) as fh: fh.write(...)``.

    Parameters
    ----------
    path : str or os.PathLike
    overwrite : bool
        Whether an existing ``path`` may be replaced. If False, the write can never replace a
        file: the finished temporary is hard-linked to ``path``, which fails if the name
        exists, whoever created it meanwhile. On a file system without hard links, ``path``
        is first created empty and exclusively (``O_CREAT | O_EXCL``) to reserve the name,
        then the temporary is renamed onto it: still no other file is replaced, but for that
        moment a reader finds an empty file, and a writer with ``overwrite=True`` that writes
        in it loses its file.
    exists_message : str, optional
        The message of the ``FileExistsError`` raised when ``path`` exists and ``overwrite``
        is False.

    Yields
    ------
    file
        A binary file open for writing on the temporary. It is created with ``open(...,
        "xb")``, so it takes the umask's permissions like any file the user writes (not
        ``mkstemp``'s private ones), and never truncates another file. A file it replaces
        keeps its permission bits (not its owner or group).

    Raises
    ------
    FileExistsError
        ``path`` exists and ``overwrite`` is False (checked before writing, and by the link
        itself); the temporary is removed.
    """
    path = Path(path)
    message = exists_message or f"{path}: already exists"
    if not overwrite and os.path.lexists(path):
        raise FileExistsError(message)
    tmp = temporary(path)
    try:
        with open(tmp, "xb") as fh:
            yield fh
            fh.flush()
            if overwrite:
                _keep_mode(path, tmp)
            os.fsync(fh.fileno())
        if overwrite:
            os.replace(tmp, path)
        else:
            _link_new(tmp, path, message)
            tmp.unlink(missing_ok=True)  # before the sync, so that no second name survives
        sync_folder(path.parent)
    finally:
        tmp.unlink(missing_ok=True)


@contextlib.contextmanager
def scratch(path):
    """Write a scratch file whole: ``with scratch(path) as fh: fh.write(...)``. As
    :func:`replacing`, a temporary renamed onto ``path`` when complete, so that a reader (or a
    task run again meanwhile) finds the whole file or none; not synced to the disk, since a
    crash loses the scratch folder with it."""
    path = Path(path)
    tmp = temporary(path)
    try:
        with open(tmp, "xb") as fh:
            yield fh
        os.replace(tmp, path)
    finally:
        tmp.unlink(missing_ok=True)


def _keep_mode(path, tmp):
    """``path``'s permission bits given to ``tmp`` where both are files, or both folders."""
    try:
        mode = os.stat(path).st_mode
    except OSError:
        return
    if stat.S_IFMT(mode) == stat.S_IFMT(os.stat(tmp).st_mode):
        os.chmod(tmp, stat.S_IMODE(mode))


def _link_new(tmp, path, message):
    """``tmp`` (a file) given the name ``path`` where no file has it, else FileExistsError;
    ``tmp`` keeps its own name too (the caller removes it)."""
    try:
        os.link(tmp, path)
        return
    except FileExistsError:
        raise FileExistsError(message) from None
    except OSError:
        pass  # no hard links here (some network and FUSE file systems): reserve the name
    try:
        handle = os.open(path, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o666)
    except FileExistsError:
        raise FileExistsError(message) from None
    reserved = os.fstat(handle)
    os.close(handle)  # an open file cannot be replaced on Windows
    try:
        os.replace(tmp, path)
    except BaseException:
        with contextlib.suppress(OSError):
            if os.path.samestat(reserved, os.stat(path)):
                os.unlink(path)  # still the empty file reserved above
        raise


def sync_folder(folder):
    """Sync ``folder``'s entries (a rename in it) to the disk, where the platform can (not on
    Windows, where a folder cannot be opened, nor on file systems that refuse)."""
    try:
        fd = os.open(folder, os.O_RDONLY | getattr(os, "O_DIRECTORY", 0))
    except OSError:
        return
    try:
        with contextlib.suppress(OSError):
            os.fsync(fd)
    finally:
        os.close(fd)


def sync(path):
    """Flush a file written by other means (a library that opens it by name) to the disk
    before it is renamed into place; for a folder (a Zarr store), every file and folder in
    it."""
    path = Path(path)
    if not path.is_dir():
        if path.is_file():
            _sync_file(path)
        return
    for folder, _, files in os.walk(path, topdown=False):
        for name in files:
            _sync_file(Path(folder, name))
        sync_folder(folder)


def _sync_file(path):
    with open(path, "rb") as fh:
        os.fsync(fh.fileno())


def replace(source, destination, *, overwrite=True, exists_message=None):
    """``source`` (synced by :func:`sync`, a file or a folder) renamed onto ``destination``.

    A file replacing a file is one rename (and keeps the old file's permission bits). A
    folder (a Zarr store) replacing anything, or anything replacing a folder, is swapped with
    it in one step where the system can (Linux's ``renameat2`` with ``RENAME_EXCHANGE``), so
    ``destination`` always names the old store or the new one; the old one is then removed.
    Elsewhere (other systems, file systems without the swap) the old one is first renamed
    aside under :func:`temporary`'s name: between the two renames ``destination`` is
    missing, and a crash there leaves the old store under that hidden name.

    With ``overwrite=False`` nothing at ``destination`` is ever replaced: a file is linked as
    by :func:`replacing`; a folder is renamed with ``RENAME_NOREPLACE``, or where that is
    missing onto an empty folder created exclusively to reserve the name (a rename replaces
    only an empty folder). ``FileExistsError`` (``exists_message``) leaves ``source`` to the
    caller.
    """
    source, destination = Path(source), Path(destination)
    message = exists_message or f"{destination}: already exists"
    if not overwrite:
        if source.is_dir():
            _rename_new_folder(source, destination, message)
        else:
            _link_new(source, destination, message)
            source.unlink(missing_ok=True)
    elif source.is_dir() or destination.is_dir():
        _keep_mode(destination, source)
        _swap_in(source, destination)
    else:
        _keep_mode(destination, source)
        os.replace(source, destination)
    sync_folder(destination.parent)


def _swap_in(source, destination):
    """``source`` renamed onto ``destination`` where either is a folder; the old one removed."""
    try:
        swapped = _renameat2(source, destination, _RENAME_EXCHANGE)
    except FileNotFoundError:  # nothing at destination: a plain rename
        os.replace(source, destination)
        return
    if swapped:
        old = source
    else:
        old = temporary(destination)
        os.replace(destination, old)
        os.replace(source, destination)
    sync_folder(destination.parent)  # the new one in place before the old one goes
    if old.is_dir():
        shutil.rmtree(old)
    else:
        old.unlink()


def _rename_new_folder(source, destination, message):
    try:
        if _renameat2(source, destination, _RENAME_NOREPLACE):
            return
    except FileExistsError:
        raise FileExistsError(message) from None
    try:
        os.mkdir(destination)
    except FileExistsError:
        raise FileExistsError(message) from None
    try:
        os.replace(source, destination)
    except BaseException:
        with contextlib.suppress(OSError):
            os.rmdir(destination)  # only while still empty: ours
        raise


def _renameat2(source, destination, flags):
    """Linux's ``renameat2``: True when done, False where the system or the file system
    lacks it or the flag; any other failure raises its ``OSError``."""
    call = _libc_renameat2()
    if call is None:
        return False
    if call(_AT_FDCWD, os.fsencode(source), _AT_FDCWD, os.fsencode(destination), flags) == 0:
        return True
    code = ctypes.get_errno()
    if code in (errno.ENOSYS, errno.EINVAL, errno.ENOTSUP, errno.EOPNOTSUPP):
        return False
    raise OSError(code, os.strerror(code), str(source), None, str(destination))


@functools.cache
def _libc_renameat2():
    """The C library's ``renameat2``, or None (not Linux, or a C library without it)."""
    if not sys.platform.startswith("linux"):
        return None
    try:
        call = ctypes.CDLL(None, use_errno=True).renameat2
    except (OSError, AttributeError):
        return None
    call.argtypes = [ctypes.c_int, ctypes.c_char_p, ctypes.c_int, ctypes.c_char_p,
                     ctypes.c_uint]
    call.restype = ctypes.c_int
    return call

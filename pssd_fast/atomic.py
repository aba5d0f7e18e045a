"""Files written whole or not at all.

Every file the library writes for a user or for a later task goes through :func:`replacing`:
the bytes go to a temporary file beside the destination, with a name no other writer shares,
created exclusively; it is flushed and synced to the disk, then renamed onto the destination.
A reader sees the old file or the new one, never a part. Two writers of one file (a task run
again while the worker thought lost still runs, two hosts sharing a folder) each write their
own temporary, and the last rename wins with a whole file.
"""
import contextlib
import os
import secrets
import shutil
from pathlib import Path


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
        Whether an existing ``path`` may be replaced. Checked again just before the rename,
        since another writer may have created it meanwhile.
    exists_message : str, optional
        The message of the ``FileExistsError`` raised when ``path`` exists and ``overwrite``
        is False.

    Yields
    ------
    file
        A binary file open for writing on the temporary. It is created with ``open(...,
        "xb")``, so it takes the umask's permissions like any file the user writes (not
        ``mkstemp``'s private ones), and never truncates another file.

    Raises
    ------
    FileExistsError
        ``path`` exists and ``overwrite`` is False; the temporary is removed.
    """
    path = Path(path)

    def refuse():
        if not overwrite and path.exists():
            raise FileExistsError(exists_message or f"{path}: already exists")

    refuse()
    tmp = temporary(path)
    try:
        with open(tmp, "xb") as fh:
            yield fh
            fh.flush()
            os.fsync(fh.fileno())
        refuse()
        os.replace(tmp, path)
    except BaseException:
        tmp.unlink(missing_ok=True)
        raise


def sync(path):
    """Flush a file written by other means (a library that opens it by name) to the disk
    before it is renamed into place; a folder (a Zarr store) is left as it is."""
    if Path(path).is_file():
        with open(path, "rb+") as fh:
            os.fsync(fh.fileno())


def replace(source, destination):
    """``source`` (a synced temporary) renamed onto ``destination``; a folder there (a Zarr
    store) is moved aside under a name of its own first and removed after."""
    source, destination = Path(source), Path(destination)
    if not destination.is_dir():
        os.replace(source, destination)
        return
    old = temporary(destination)
    os.replace(destination, old)
    os.replace(source, destination)
    shutil.rmtree(old)

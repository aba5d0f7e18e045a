"""Files written whole or not at all (pssd_fast.atomic), by every writer of the package."""
import contextlib
import errno
import multiprocessing
import os
import re
import signal
import stat
import subprocess
import sys
import threading
from pathlib import Path

import numpy as np
import pytest

import pssd_fast
from pssd_fast import atomic
from pssd_fast.tiled import ondisk


def leftovers(folder):
    return sorted(p.name for p in Path(folder).iterdir() if ".partial" in p.name)


def test_replacing_writes_syncs_and_renames(tmp_path, monkeypatch):
    synced = []
    real_fsync = os.fsync
    monkeypatch.setattr(os, "fsync", lambda fd: (synced.append(fd), real_fsync(fd)))
    path = tmp_path / "a.bin"
    path.write_bytes(b"old")
    with atomic.replacing(path) as fh:
        fh.write(b"new")
        assert path.read_bytes() == b"old"  # nothing reaches the destination before the end
        assert len(leftovers(tmp_path)) == 1
    assert path.read_bytes() == b"new" and synced and leftovers(tmp_path) == []


def test_a_failed_write_keeps_the_old_file_and_leaves_no_temporary(tmp_path):
    path = tmp_path / "a.bin"
    path.write_bytes(b"old")
    with pytest.raises(RuntimeError, match="disk full"):
        with atomic.replacing(path) as fh:
            fh.write(b"half")
            raise RuntimeError("disk full")
    assert path.read_bytes() == b"old" and leftovers(tmp_path) == []


def test_no_overwrite_refuses_before_and_after_writing(tmp_path):
    path = tmp_path / "a.bin"
    path.write_bytes(b"old")
    with pytest.raises(FileExistsError, match="mine"):
        with atomic.replacing(path, overwrite=False, exists_message="mine"):
            pass
    other = tmp_path / "b.bin"
    with pytest.raises(FileExistsError, match="already exists"):
        with atomic.replacing(other, overwrite=False) as fh:
            fh.write(b"late")
            other.write_bytes(b"first")  # another writer got there meanwhile
    assert path.read_bytes() == b"old" and other.read_bytes() == b"first"
    assert leftovers(tmp_path) == []


#: Load ``atomic.py`` alone (it imports nothing of the package), so that a child starts fast.
LOAD = """
import importlib.util, sys, time
from pathlib import Path
spec = importlib.util.spec_from_file_location("atomic", sys.argv[1])
atomic = importlib.util.module_from_spec(spec)
spec.loader.exec_module(atomic)
"""
#: Run in a child, writer ``argv[3]`` of ``argv[4]``: ``argv[5]`` rounds of writing a new
#: ``race<round>.bin`` in ``argv[2]`` with ``overwrite=False``; print each round's outcome. The
#: writers start each round together, and each waits for the others again just before the call
#: that gives its file the name (``os.link`` or ``os.replace``, wrapped here): the worst moment
#: for a writer that checks the name, then renames.
RACE = LOAD + """
import os
folder, me, writers, rounds = Path(sys.argv[2]), *map(int, sys.argv[3:6])
flags = folder / "flags"

def meet(name):
    (flags / f"{name}.{me}").touch()
    deadline = time.monotonic() + 60
    while len(list(flags.glob(f"{name}.*"))) < writers:
        if time.monotonic() > deadline:
            sys.exit(f"the other writers never reached {name}")
        time.sleep(0.001)

def meeting_first(call):
    def wrapped(source, destination):
        meet(f"name{Path(destination).name}")
        return call(source, destination)
    return wrapped

os.link, os.replace = meeting_first(os.link), meeting_first(os.replace)
for round_ in range(rounds):
    meet(f"start{round_}")
    try:
        with atomic.replacing(folder / f"race{round_}.bin", overwrite=False) as fh:
            fh.write(bytes([me]) * 100_000)
        print(round_, "won", flush=True)
    except FileExistsError:
        print(round_, "refused", flush=True)
"""


def test_writers_racing_without_overwrite_never_clobber(tmp_path):
    """Three processes write one new path with ``overwrite=False`` and reach the name at once:
    exactly one wins, the others are refused, and the file holds the winner's bytes alone. (A
    check of the name followed by a rename lets all three through.)"""
    writers, rounds = 3, 4
    (tmp_path / "flags").mkdir()
    children = [subprocess.Popen([sys.executable, "-c", RACE, atomic.__file__,
                                  *map(str, (tmp_path, me, writers, rounds))],
                                 stdout=subprocess.PIPE, text=True)
                for me in range(1, writers + 1)]
    outcomes = [child.communicate(timeout=120)[0].split() for child in children]
    assert [child.returncode for child in children] == [0] * writers
    for round_ in range(rounds):
        said = {me: outcome[2 * round_ + 1] for me, outcome in enumerate(outcomes, 1)}
        assert sorted(said.values()) == ["refused"] * (writers - 1) + ["won"], said
        won, = (me for me, what in said.items() if what == "won")
        assert (tmp_path / f"race{round_}.bin").read_bytes() == bytes([won]) * 100_000
    assert leftovers(tmp_path) == []


#: Run in a child: write two files, the second new and with ``overwrite=False``; stop in the
#: middle, and wait to be killed.
KILLED = LOAD + """
with atomic.replacing(sys.argv[2]) as a, atomic.replacing(sys.argv[3], overwrite=False) as b:
    a.write(b"half of the new"); b.write(b"half of the new")
    a.flush(); b.flush()
    print("writing", flush=True)
    time.sleep(60)
"""


@pytest.mark.skipif(os.name != "posix", reason="SIGKILL")
def test_a_killed_writer_leaves_the_old_file_and_nothing_that_blocks_the_next(tmp_path):
    """A writer killed in the middle leaves the destination as it was (or absent) and its
    hidden temporaries, which stay (see ``pssd_fast/atomic.py``) but block no later write,
    with or without ``overwrite``, and are no output."""
    old, new = tmp_path / "old.laz", tmp_path / "new.laz"
    old.write_bytes(b"old")
    child = subprocess.Popen([sys.executable, "-c", KILLED, atomic.__file__, old, new],
                             stdout=subprocess.PIPE, text=True)
    assert child.stdout.readline() == "writing\n"
    os.kill(child.pid, signal.SIGKILL)
    child.wait()
    child.stdout.close()
    assert child.returncode == -signal.SIGKILL
    assert old.read_bytes() == b"old" and not new.exists()
    left = leftovers(tmp_path)
    assert len(left) == 2 and all(name.startswith(".") for name in left)
    with atomic.replacing(old) as fh:
        fh.write(b"whole")
    with atomic.replacing(new, overwrite=False) as fh:
        fh.write(b"whole")
    assert old.read_bytes() == new.read_bytes() == b"whole" and leftovers(tmp_path) == left


def test_a_replaced_file_keeps_its_mode_and_a_new_one_takes_the_umask(tmp_path):
    path = tmp_path / "a.bin"
    path.write_bytes(b"old")
    path.chmod(0o640)
    with atomic.replacing(path) as fh:
        fh.write(b"new")
    assert stat.S_IMODE(path.stat().st_mode) == 0o640
    umask = os.umask(0)
    os.umask(umask)
    with atomic.replacing(tmp_path / "b.bin", overwrite=False) as fh:
        fh.write(b"new")
    assert stat.S_IMODE((tmp_path / "b.bin").stat().st_mode) == 0o666 & ~umask
    written = atomic.temporary(path)  # as a library writing by name leaves it
    written.write_bytes(b"newer")
    atomic.replace(written, path)
    assert stat.S_IMODE(path.stat().st_mode) == 0o640 and path.read_bytes() == b"newer"


@contextlib.contextmanager
def spying_fsync(watched=lambda: None):
    """Record each ``os.fsync``: whether it synced a folder, and ``watched()`` at that time."""
    calls = []
    real_fsync = os.fsync

    def fsync(fd):
        calls.append((stat.S_ISDIR(os.fstat(fd).st_mode), watched()))
        return real_fsync(fd)

    os.fsync = fsync
    try:
        yield calls
    finally:
        os.fsync = real_fsync


@pytest.mark.parametrize("overwrite", [True, False])
def test_the_folder_is_synced_after_the_rename(tmp_path, overwrite):
    path = tmp_path / "a.bin"
    with spying_fsync(lambda: path.exists() and path.read_bytes()) as calls:
        with atomic.replacing(path, overwrite=overwrite) as fh:
            fh.write(b"new")
    # The file before the rename, then its folder with the new name in it.
    assert calls == [(False, False), (True, b"new")]


def test_without_hard_links_a_no_clobber_write_still_cannot_clobber(tmp_path, monkeypatch):
    def no_links(source, destination):
        raise PermissionError(errno.EPERM, "hard links not supported")

    monkeypatch.setattr(os, "link", no_links)
    path = tmp_path / "a.bin"
    with atomic.replacing(path, overwrite=False) as fh:
        fh.write(b"mine")
    assert path.read_bytes() == b"mine"
    other = tmp_path / "b.bin"
    with pytest.raises(FileExistsError, match="already exists"):
        with atomic.replacing(other, overwrite=False) as fh:
            fh.write(b"late")
            other.write_bytes(b"first")
    assert other.read_bytes() == b"first" and leftovers(tmp_path) == []
    written = atomic.temporary(other)  # as a library writing by name leaves it
    written.write_bytes(b"by name")
    with pytest.raises(FileExistsError):
        atomic.replace(written, other, overwrite=False)
    assert other.read_bytes() == b"first" and written.read_bytes() == b"by name"
    atomic.replace(written, tmp_path / "c.bin", overwrite=False)
    assert (tmp_path / "c.bin").read_bytes() == b"by name" and leftovers(tmp_path) == []


def test_a_file_written_by_name_is_linked_without_overwrite(tmp_path):
    path = tmp_path / "a.las"
    written = atomic.temporary(path)
    written.write_bytes(b"by name")
    atomic.replace(written, path, overwrite=False)
    assert path.read_bytes() == b"by name" and leftovers(tmp_path) == []
    written.write_bytes(b"again")
    with pytest.raises(FileExistsError, match="taken"):
        atomic.replace(written, path, overwrite=False, exists_message="taken")
    assert path.read_bytes() == b"by name" and written.read_bytes() == b"again"


def _store(folder, files):
    """A folder standing for a Zarr store: ``files`` maps relative names to contents."""
    for name, content in files.items():
        (folder / name).parent.mkdir(parents=True, exist_ok=True)
        (folder / name).write_bytes(content)
    return folder


def _read_store(folder):
    return {str(p.relative_to(folder)): p.read_bytes() for p in folder.rglob("*") if p.is_file()}


NEW_STORE = {"c/0.0": b"new chunk", "c/0.1": b"another", ".zarray": b"{}"}


@pytest.mark.parametrize("swap", ["exchange", "aside"])
def test_a_store_replaces_a_store_synced_and_whole(tmp_path, monkeypatch, swap):
    """Every file and folder of the new store is synced before it takes the name; the old
    store goes. With the swap (Linux) the name never goes missing (a reader polls it in a
    thread); the portable way moves the old store aside first."""
    if swap == "aside":
        monkeypatch.setattr(atomic, "_renameat2", lambda source, destination, flags: False)
    elif atomic._libc_renameat2() is None:
        pytest.skip("no renameat2 here")
    destination = _store(tmp_path / "out.zarr", {"c/0.0": b"old chunk", "old": b"x"})
    missing, done = [], threading.Event()

    def poll():
        while not done.is_set():
            if not os.path.exists(destination):
                missing.append(1)

    reader = threading.Thread(target=poll)
    reader.start()
    try:
        for _ in range(20):
            source = _store(atomic.temporary(destination), NEW_STORE)
            with spying_fsync() as synced:
                atomic.sync(source)
            assert sum(not is_dir for is_dir, _ in synced) == 3  # each file
            assert sum(is_dir for is_dir, _ in synced) == 2  # the store and its folder c
            atomic.replace(source, destination)
    finally:
        done.set()
        reader.join()
    assert _read_store(destination) == NEW_STORE and leftovers(tmp_path) == []
    if swap == "exchange":
        assert not missing


def test_a_store_and_a_file_replace_each_other(tmp_path):
    destination = tmp_path / "out"
    destination.write_bytes(b"a file")
    source = _store(atomic.temporary(destination), NEW_STORE)
    atomic.replace(source, destination)
    assert _read_store(destination) == NEW_STORE
    source = atomic.temporary(destination)
    source.write_bytes(b"a file again")
    atomic.replace(source, destination)
    assert destination.read_bytes() == b"a file again" and leftovers(tmp_path) == []


@pytest.mark.parametrize("rename", ["noreplace", "reserve"])
def test_a_store_without_overwrite_never_replaces_one_made_meanwhile(tmp_path, monkeypatch,
                                                                     rename):
    if rename == "reserve":
        monkeypatch.setattr(atomic, "_renameat2", lambda source, destination, flags: False)
    destination = tmp_path / "out.zarr"
    source = _store(atomic.temporary(destination), NEW_STORE)
    atomic.replace(source, destination, overwrite=False)
    assert _read_store(destination) == NEW_STORE
    source = _store(atomic.temporary(destination), {"late": b"late"})
    with pytest.raises(FileExistsError, match="taken"):
        atomic.replace(source, destination, overwrite=False, exists_message="taken")
    assert _read_store(destination) == NEW_STORE and _read_store(source) == {"late": b"late"}
    empty = tmp_path / "empty.zarr"
    empty.mkdir()  # another writer's store, not written yet
    with pytest.raises(FileExistsError):
        atomic.replace(source, empty, overwrite=False)
    assert not any(empty.iterdir())


def test_temporary_names_are_unique_hidden_and_keep_the_suffix(tmp_path):
    names = {atomic.temporary(tmp_path / "out.laz") for _ in range(100)}
    assert len(names) == 100
    for name in names:
        assert name.parent == tmp_path and name.name.startswith(".out.")
        assert name.suffix == ".laz" and ".partial" in name.name


def _write_parts(path, value, rounds, start):
    """A writer of one part: ``rounds`` times the whole part, all ``value``."""
    records = np.zeros(20_000, ondisk.PART)
    records["row"] = value
    start.wait()
    for _ in range(rounds):
        ondisk.save(records, path)


def test_two_writers_of_one_part_never_corrupt_it(tmp_path):
    """A task run again while the first worker still writes: whatever a reader finds is one
    writer's whole part."""
    path = tmp_path / "part.bin"
    context = multiprocessing.get_context("spawn")
    start = context.Event()
    writers = [context.Process(target=_write_parts, args=(path, value, 60, start))
               for value in (1, 2)]
    for writer in writers:
        writer.start()
    start.set()
    seen = set()
    while any(writer.is_alive() for writer in writers):
        if path.exists():
            records = np.fromfile(path, ondisk.PART)
            assert records.shape == (20_000,)
            values = np.unique(records["row"])
            assert values.shape == (1,) and values[0] in (1, 2)
            seen.add(int(values[0]))
    for writer in writers:
        writer.join()
        assert writer.exitcode == 0
    assert np.unique(np.fromfile(path, ondisk.PART)["row"]).shape == (1,)
    assert seen and leftovers(tmp_path) == []


def test_every_writer_goes_through_the_helper():
    """No module but the helper renames a file into place or names a temporary itself."""
    package = Path(pssd_fast.__file__).parent
    renaming = re.compile(r"os\.(replace|rename)\(|\.partial|getpid\(")
    found = sorted(str(path.relative_to(package)) for path in package.rglob("*.py")
                   if renaming.search(path.read_text()))
    assert found == ["atomic.py"]

"""Files written whole or not at all (pssd_fast.atomic), by every writer of the package."""
import multiprocessing
import os
import re
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

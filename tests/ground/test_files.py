"""User outputs: written whole or not at all, never onto an input."""

import errno
import os

import pytest

from lodestar.cli import main
from lodestar.ground import files


def test_write_atomic_replaces_whole_or_leaves_the_old_file(tmp_path, monkeypatch):
    target = tmp_path / "db.bin"
    files.write_atomic(target, b"good" * 1000)
    real_fsync = os.fsync

    def full_disk(fd):
        raise OSError(errno.ENOSPC, "No space left on device")

    monkeypatch.setattr(os, "fsync", full_disk)
    with pytest.raises(OSError, match="No space left"):
        files.write_atomic(target, b"new" * 100000)
    monkeypatch.setattr(os, "fsync", real_fsync)
    assert target.read_bytes() == b"good" * 1000
    assert [p.name for p in tmp_path.iterdir()] == ["db.bin"]        # no temporary left
    with pytest.raises(FileNotFoundError, match="the folder .*sub does not exist"):
        files.write_atomic(tmp_path / "sub" / "t.txt", "text")
    assert not (tmp_path / "sub").exists()                         # no folder made
    files.write_atomic(tmp_path / "sub" / "t.txt", "text", folders=True)   # a cache's
    assert (tmp_path / "sub" / "t.txt").read_text() == "text"
    umask = os.umask(0o022)
    try:
        files.write_atomic(tmp_path / "new.bin", b"x")
    finally:
        os.umask(umask)
    assert (tmp_path / "new.bin").stat().st_mode & 0o777 == 0o644     # not mkstemp's 0600
    os.chmod(target, 0o640)
    files.write_atomic(target, b"again")
    assert target.stat().st_mode & 0o777 == 0o640                    # the replaced file's


def test_db_build_on_a_full_disk_keeps_the_database_it_would_replace(tmp_path, monkeypatch,
                                                                      capsys):
    """Issue 19, item 5: ``db build -o`` over a valid database on a full disk exits 2 and
    leaves that database whole (it was truncated to 204,800 of 519,700 bytes)."""
    out = tmp_path / "db.bin"
    assert main(["db", "build", "--fov", "20", "--mag", "4.5", "-o", str(out)]) == 0
    before = out.read_bytes()
    monkeypatch.setattr(os, "fsync", lambda fd: (_ for _ in ()).throw(
        OSError(errno.ENOSPC, "No space left on device")))
    capsys.readouterr()
    assert main(["db", "build", "--fov", "21", "--mag", "4.5", "-o", str(out),
                 "--force"]) == 2
    assert "No space left" in capsys.readouterr().err
    assert out.read_bytes() == before


def test_check_output(tmp_path):
    source = tmp_path / "in.png"
    source.write_bytes(b"x")
    files.check_output(tmp_path / "out.png", (".png",), inputs=[source])
    files.check_output(tmp_path / "OUT.PNG", (".png",), inputs=[source])
    with pytest.raises(ValueError, match="must end in .png"):
        files.check_output(tmp_path / "out.tif", (".png",))
    with pytest.raises(ValueError, match="is an input of this command"):
        files.check_output(tmp_path / "." / "in.png", (".png",), inputs=[source])
    files.check_output(tmp_path / "other.png", (".png",), force=True)
    (tmp_path / "old.png").write_bytes(b"y")
    with pytest.raises(ValueError, match="old.png exists; give --force to replace it"):
        files.check_output(tmp_path / "old.png", (".png",), inputs=[source])
    files.check_output(tmp_path / "old.png", (".png",), inputs=[source], force=True)
    with pytest.raises(ValueError, match="the folder .*missing does not exist"):
        files.check_output(tmp_path / "missing" / "out.png", (".png",), force=True)
    (tmp_path / "d.png").mkdir()
    with pytest.raises(ValueError, match="d.png is a folder"):
        files.check_output(tmp_path / "d.png", (".png",), force=True)
    files.check_output(tmp_path / "any.name", None)


COMMANDS = [          # every output a user names; each is checked before any work
    (["solve", "{image}", "--annotate", "{out}.png"], "--annotate"),
    (["solve", "{image}", "--wcs", "{out}.wcs"], "--wcs"),
    (["calibrate", "{image}", "--fov", "20", "-o", "{out}.json"], "--out"),
    (["db", "build", "--fov", "20", "--mag", "4.5", "-o", "{out}.bin"], "-o"),
    (["simulate", "-o", "{out}"], "-o"),
    (["demo", "--out", "{out}.png"], "--out"),
]


@pytest.mark.parametrize("args, what", COMMANDS, ids=lambda a: " ".join(a[:2]))
def test_every_named_output_is_refused_over_a_file_or_into_a_missing_folder(
        args, what, tmp_path, capsys):
    """Issue 33: one rule for every output a user names: an existing file is replaced only
    with --force, and a missing folder is an error (exit 2, one line), never created."""
    image = tmp_path / "in.png"
    image.write_bytes(b"not read")
    existing = tmp_path / "old"
    for suffix in (".png", ".wcs", ".json", ".bin", "_preview.png"):
        existing.with_name("old" + suffix).write_bytes(b"keep")
    for out, message in ((existing, "exists; give --force to replace it"),
                         (tmp_path / "nowhere" / "new", "nowhere does not exist")):
        argv = [a.format(image=image, out=out) for a in args]
        assert main(argv) == 2, argv
        err = capsys.readouterr().err
        assert err.count("\n") == 1 and message in err and what in err, err
    assert not (tmp_path / "nowhere").exists()
    assert all(p.read_bytes() == b"keep" for p in tmp_path.glob("old*"))

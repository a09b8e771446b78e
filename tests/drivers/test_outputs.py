"""Outputs are never written in place: engine/core/outputs.py."""

import os

import pytest

from stillpoint.engine.core.outputs import (AtomicOutput, OutputError, atomic_output,
                                        check_distinct_outputs, check_output_folder,
                                        check_output_path, partial_path, protect_inputs)


def test_complete_output_replaces_only_at_commit(tmp_path):
    out = tmp_path / "a.csv"
    out.write_text("old complete\n")
    with atomic_output(out, binary=False) as f:
        f.write("new\n")
        assert out.read_text() == "old complete\n"  # untouched while writing
        assert partial_path(out).exists()
    assert out.read_text() == "new\n" and not partial_path(out).exists()


def test_interrupted_write_keeps_previous_output_and_partial(tmp_path):
    out = tmp_path / "a.bin"
    out.write_bytes(b"previous")
    with pytest.raises(KeyboardInterrupt):
        with atomic_output(out) as f:
            f.write(b"half")
            raise KeyboardInterrupt
    assert out.read_bytes() == b"previous"
    assert partial_path(out).read_bytes() == b"half"


def test_empty_partial_removed_on_error(tmp_path):
    out = tmp_path / "a.bin"
    with pytest.raises(RuntimeError):
        with atomic_output(out):
            raise RuntimeError("before any byte")
    assert not partial_path(out).exists() and not out.exists()


def test_second_writer_refused(tmp_path):
    out = tmp_path / "a.mcap"
    first = AtomicOutput(out)
    with pytest.raises(OutputError, match="another stillpoint run"):
        AtomicOutput(out)
    first.file.write(b"x")
    first.commit()
    assert out.read_bytes() == b"x"


def test_stale_partial_of_killed_run_is_kept_aside(tmp_path):
    out = tmp_path / "a.mcap"
    partial_path(out).write_bytes(b"salvageable")
    w = AtomicOutput(out)
    assert w.set_aside is not None and w.set_aside.read_bytes() == b"salvageable"
    w.file.write(b"fresh")
    w.commit()
    assert out.read_bytes() == b"fresh"


@pytest.mark.parametrize("case", ["missing", "notdir", "isdir", "readonly"])
def test_bad_destinations_refused_before_work(tmp_path, case):
    if case == "missing":
        p = tmp_path / "nope" / "a.mcap"
    elif case == "notdir":
        (tmp_path / "f").write_text("")
        p = tmp_path / "f" / "a.mcap"
    elif case == "isdir":
        p = tmp_path
    else:
        if os.geteuid() == 0:
            pytest.skip("root can write into a read-only folder (permission bits are not enforced)")
        ro = tmp_path / "ro"
        ro.mkdir()
        ro.chmod(0o500)
        p = ro / "a.mcap"
    with pytest.raises(OutputError) as e:
        check_output_path(p)
    assert str(p) in str(e.value) or str(p.parent) in str(e.value)


@pytest.mark.parametrize("via_link", [False, True])
def test_device_pipe_or_socket_refused_not_replaced(tmp_path, via_link):
    """A destination that is not a regular file (a device such as /dev/null, a named pipe,
    a socket; links followed) is refused before any work: the rename that completes an output
    would otherwise put a plain file in its place."""
    import socket
    import stat
    fifo = tmp_path / "pipe"
    os.mkfifo(fifo)
    sock_path = tmp_path / "sock"
    sock = socket.socket(socket.AF_UNIX)
    sock.bind(str(sock_path))
    try:
        for target, kind in ((fifo, "a pipe"), (sock_path, "a socket")):
            p = target
            if via_link:
                p = tmp_path / (target.name + ".link")
                p.symlink_to(target)
            with pytest.raises(OutputError) as e:
                AtomicOutput(p)
            assert str(p) in str(e.value) and kind in str(e.value)
            assert not partial_path(p).exists()
        assert stat.S_ISFIFO(os.stat(fifo).st_mode)
    finally:
        sock.close()
    if os.path.exists("/dev/null"):  # checked only: the refusal comes before anything is opened
        with pytest.raises(OutputError) as e:
            check_output_path("/dev/null")
        assert "a character device" in str(e.value)


def test_output_folder_checked_for_what_it_is(tmp_path):
    """A destination folder (the station's, a device download's) that is missing, a file or a
    pipe is refused with what it is."""
    (tmp_path / "f").write_text("")
    os.mkfifo(tmp_path / "p")
    for name, msg in (("nope", "output folder does not exist"),
                      ("f", "output folder is a file, not a folder"),
                      ("p", "output folder is a pipe, not a folder")):
        with pytest.raises(OutputError, match=msg) as e:
            check_output_folder(tmp_path / name)
        assert str(tmp_path / name) in str(e.value)
    assert check_output_folder(tmp_path) == tmp_path


def test_protected_input_is_never_an_output_however_spelled(tmp_path, monkeypatch):
    """An input of the running command is refused as an output through a symlink, a hard link
    or a relative path, and only while it is protected."""
    rec = tmp_path / "rec.cwa"
    rec.write_bytes(b"MD recording bytes")
    (tmp_path / "link.cwa").symlink_to(rec)
    os.link(rec, tmp_path / "hard.cwa")
    monkeypatch.chdir(tmp_path)
    protect_inputs([rec])
    try:
        for p in (rec, tmp_path / "link.cwa", tmp_path / "hard.cwa", "rec.cwa"):
            with pytest.raises(OutputError, match="summary would overwrite the input"):
                check_output_path(p, what="summary")
            with pytest.raises(OutputError, match="would overwrite the input"):
                AtomicOutput(p)
    finally:
        protect_inputs(())
    assert rec.read_bytes() == b"MD recording bytes"
    assert check_output_path(rec) == rec  # no longer an input


def test_two_outputs_of_one_command_may_not_be_one_file(tmp_path):
    check_distinct_outputs({"MCAP output": tmp_path / "a.mcap", "summary": None,
                            "plot": tmp_path / "a.png"})
    with pytest.raises(OutputError, match="the summary and the MCAP output are the same file"):
        check_distinct_outputs({"MCAP output": tmp_path / "a.mcap",
                                "summary": tmp_path / "x" / ".." / "a.mcap"})


# ---------------------------------------------------------------------------- links never followed
def _outside(tmp_path):
    secret = tmp_path / "elsewhere" / "precious.txt"
    secret.parent.mkdir()
    secret.write_bytes(b"precious")
    out = tmp_path / "out"
    out.mkdir()
    return secret, out


def test_a_destination_that_is_a_symlink_is_refused(tmp_path):
    secret, out = _outside(tmp_path)
    for target in (secret, tmp_path / "elsewhere" / "missing.txt"):
        link = out / "a.csv"
        link.symlink_to(target)
        with pytest.raises(OutputError, match="symbolic link") as e:
            AtomicOutput(link)
        assert str(link) in str(e.value)
        assert not partial_path(link).exists() and link.is_symlink()
        link.unlink()
    assert secret.read_bytes() == b"precious"
    assert not (tmp_path / "elsewhere" / "missing.txt").exists()


@pytest.mark.parametrize("dangling", [False, True])
def test_a_planted_part_link_never_receives_a_byte(tmp_path, dangling):
    secret, out = _outside(tmp_path)
    target = (tmp_path / "elsewhere" / "created.txt") if dangling else secret
    partial_path(out / "a.bin").symlink_to(target)
    for attempt in (lambda: check_output_path(out / "a.bin"), lambda: AtomicOutput(out / "a.bin")):
        with pytest.raises(OutputError, match="symbolic link") as e:
            attempt()
        assert str(partial_path(out / "a.bin")) in str(e.value)
    assert secret.read_bytes() == b"precious" and not (tmp_path / "elsewhere" / "created.txt").exists()
    assert partial_path(out / "a.bin").is_symlink() and not (out / "a.bin").exists()


@pytest.mark.parametrize("content", [b"", b"half a run"])
def test_a_part_hard_linked_elsewhere_is_never_written_through(tmp_path, content):
    secret, out = _outside(tmp_path)
    secret.write_bytes(content)
    os.link(secret, partial_path(out / "a.bin"))
    with atomic_output(out / "a.bin") as f:
        f.write(b"new output")
    assert (out / "a.bin").read_bytes() == b"new output"
    assert secret.read_bytes() == content  # the other name's file is untouched


def test_a_part_replaced_while_written_is_not_renamed_into_place(tmp_path):
    out = tmp_path / "a.bin"
    out.write_bytes(b"previous")
    w = AtomicOutput(out)
    w.file.write(b"ours")
    os.rename(w.part, tmp_path / "moved")
    (tmp_path / "planted").write_bytes(b"not ours")
    os.symlink(tmp_path / "planted", w.part)
    with pytest.raises(OutputError, match="replaced while it was written"):
        w.commit()
    assert out.read_bytes() == b"previous" and (tmp_path / "moved").read_bytes() == b"ours"
    assert (tmp_path / "planted").read_bytes() == b"not ours"


def test_a_symlinked_destination_is_one_line_exit_2_on_the_command_line(tmp_path, capsys):
    from stillpoint.engine.sim.record import simulate_recording
    from stillpoint.tools.cli import main
    secret, out = _outside(tmp_path)
    rec = tmp_path / "r.cwa"
    simulate_recording(rec, device="ax3", days=0.002, truth_path=False)
    (out / "x.csv").symlink_to(secret)
    assert main(["export", str(rec), "-o", str(out / "x.csv")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "symbolic link" in err[0] and str(out / "x.csv") in err[0]
    assert secret.read_bytes() == b"precious"


def test_a_planted_cohort_lock_link_is_not_followed(tmp_path):
    """The per-file lock of a cohort folder is opened with O_NOFOLLOW: a link planted in its
    place never creates or opens a file elsewhere."""
    import csv
    import shutil

    from stillpoint.engine.sim.record import simulate_recording
    from stillpoint.tools.cli import main
    rec = tmp_path / "r.cwa"
    simulate_recording(rec, device="ax3", days=0.002, truth_path=False)
    co = tmp_path / "co"
    argv = ["cohort", "run", str(rec), "-o", str(co), "--scheduler", "serial", "-q"]
    assert main(argv) == 0
    with open(co / "manifest.csv", newline="") as f:
        final = co / next(csv.DictReader(f))["folder"]
    lock = final.with_name("." + final.name + ".lock")
    shutil.rmtree(final)
    lock.unlink()
    outside = tmp_path / "elsewhere" / "created.lock"
    outside.parent.mkdir()
    lock.symlink_to(outside)
    main(argv)
    assert not outside.exists() and lock.is_symlink()

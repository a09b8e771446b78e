"""The simulator's motion rendered in a child process (engine/sim/render_process.py) gives the
same chunks as rendering on a thread or inline, bit for bit; a child that cannot start or dies
mid-run only costs speed; leaving early stops the child and leaves no shared file behind."""

from __future__ import annotations

import functools
import os

import numpy as np
import pytest

from stillpoint.engine.sim import render_process
from stillpoint.engine.sim.record import build_model, make_devices

FIELDS = ("true_s", "time_ns", "true_g", "measured_g", "counts", "gyro_counts", "temperature_c")


def _sim(device="ax3", **kw):
    extra = {"gyro_range_dps": 1000.0} if device == "ax6" else {}
    [sim] = make_devices(sites=["wrist"], devices=[device], days=1.25, hz=12.5, seed=5,
                         effects=build_model("default,restarts" if device != "geneactiv" else "default"),
                         **extra, **kw)
    return sim


def _chunks(sim, prefetch):
    out = []
    for c in sim.chunks(prefetch=prefetch):
        out.append({f: None if getattr(c, f, None) is None else np.array(getattr(c, f)) for f in FIELDS}
                   | {"k": c.index, "restarts": list(c.restarts)})
    return out


def _same(a, b):
    assert len(a) == len(b)
    for x, y in zip(a, b):
        assert x["k"] == y["k"] and x["restarts"] == y["restarts"]
        for f in FIELDS:
            if x[f] is None or y[f] is None:
                assert x[f] is None and y[f] is None, f
            else:
                assert x[f].dtype == y[f].dtype and np.array_equal(x[f], y[f]), (x["k"], f)


@pytest.fixture
def shared_files(monkeypatch):
    """The shared files this test's children were given (not a folder listing: other processes
    on the machine, e.g. a parallel test worker, render in the same /dev/shm)."""
    paths = []
    orig = render_process._Child.__init__

    def init(self, sim):
        try:
            orig(self, sim)
        finally:
            if getattr(self, "path", None):
                paths.append(self.path)

    monkeypatch.setattr(render_process._Child, "__init__", init)
    return paths


def _leftovers(paths):
    assert paths, "no child was started"
    return [p for p in paths if os.path.exists(p)]


@pytest.fixture
def child_renders_all(monkeypatch):
    """The parent waits for the child (no chunk rendered while it starts); counts the chunks the
    child delivered."""
    got = []
    orig = render_process._Child.receive

    def receive(self, k):
        r = orig(self, k)
        got.append(k)
        return r

    monkeypatch.setattr(render_process._Child, "receive", receive)
    monkeypatch.setattr(render_process, "rendered",
                        functools.partial(render_process.rendered, parent_starts=False))
    return got


@pytest.mark.parametrize("device", ["ax3", "ax6", "geneactiv"])
def test_child_process_gives_the_same_chunks(device, child_renders_all, shared_files):
    ref = _chunks(_sim(device), False)
    assert len(ref) == 30
    _same(ref, _chunks(_sim(device), "thread"))
    assert not child_renders_all
    _same(ref, _chunks(_sim(device), "process"))
    assert child_renders_all == list(range(30))
    assert _leftovers(shared_files) == []


class _Dying(render_process._Child):
    """A child killed after it has delivered a few chunks."""

    def receive(self, k):
        if k == 9:
            self.proc.kill()
            self.proc.wait()
        return super().receive(k)


def test_a_child_that_dies_or_cannot_start_only_costs_speed(monkeypatch, child_renders_all):
    ref = _chunks(_sim(), False)
    monkeypatch.setattr(render_process, "_Child", _Dying)
    _same(ref, _chunks(_sim(), "process"))
    # the child rendered 0-8 (chunk 9 too if it was already in the pipe), then the parent took over
    m = len(child_renders_all)
    assert child_renders_all == list(range(m)) and 9 <= m <= 10
    monkeypatch.setattr(render_process, "_Child", render_process._Child)
    monkeypatch.setattr(render_process.sys, "executable", "/nonexistent/python")
    _same(ref, _chunks(_sim(), "process"))


def test_leaving_early_stops_the_child(shared_files):
    sim = _sim()
    gen = render_process.rendered(sim, parent_starts=False)
    procs = []
    for k, _r in gen:
        if k == 12:
            break
    frame = gen.gi_frame
    child = frame.f_locals.get("child") if frame is not None else None
    if child is not None:
        procs.append(child.proc)
    gen.close()
    for p in procs:
        assert p.poll() is not None, "the child still runs"
    assert procs, "the child never took over"
    assert _leftovers(shared_files) == []


def test_a_chunk_larger_than_its_slot_is_rendered_by_the_parent(monkeypatch, child_renders_all):
    ref = _chunks(_sim(), False)
    monkeypatch.setattr(render_process, "_slot_bytes", lambda sim: 4096)
    _same(ref, _chunks(_sim(), "process"))
    assert child_renders_all == []  # the child could not pack chunk 0 and stopped

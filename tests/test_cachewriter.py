"""The cache writer: tiles written behind the prepare step, complete or absent, bounded, failures named."""
from __future__ import annotations

import errno
import os
import re
import threading

import numpy as np
import pytest

from lunaralbedo.io import cachewriter
from lunaralbedo.io.cache import load_stack
from lunaralbedo.io.cachewriter import CacheWriter


def _leftovers(root):
    return sorted(p.name for p in root.rglob(".tmp-*"))


def _held_writes(monkeypatch):
    """Make the writer's block writes wait for ``gate``; ``started`` is set when one begins.  Returns the
    events and the real ``save_stack``."""
    gate, started = threading.Event(), threading.Event()
    real = cachewriter.save_stack

    def held(folder, arrays, meta):
        started.set()
        gate.wait(10)
        real(folder, arrays, meta)

    monkeypatch.setattr(cachewriter, "save_stack", held)
    return gate, started, real


def test_an_entry_appears_complete_once_written_and_the_caller_goes_on_meanwhile(tmp_path, monkeypatch):
    gate = threading.Event()
    real = cachewriter.save_stack

    def slow(folder, arrays, meta):
        gate.wait(10)
        real(folder, arrays, meta)

    monkeypatch.setattr(cachewriter, "save_stack", slow)
    w = CacheWriter()
    e = w.entry(tmp_path / "tile_a")
    a = np.arange(1000, dtype=np.float32)
    e.save("block_0000", {"x": a}, {"rows": [0, 1]})
    e.complete({"blocks": [[0, 1]]})  # both queued: the caller is not held by the slow write
    assert not (tmp_path / "tile_a").exists() and _leftovers(tmp_path)
    gate.set()
    w.flush()
    assert load_stack(tmp_path / "tile_a")[1] == {"blocks": [[0, 1]]}
    np.testing.assert_array_equal(load_stack(tmp_path / "tile_a" / "block_0000")[0]["x"], a)
    assert _leftovers(tmp_path) == []


def test_the_caller_waits_when_the_waiting_blocks_reach_the_byte_budget(tmp_path, monkeypatch):
    """Small blocks queue several deep, up to ``pending_bytes`` of arrays; a block bigger than that still goes
    alone, once nothing waits."""
    gate, started, real = _held_writes(monkeypatch)
    w = CacheWriter(pending=8, pending_bytes=1000)
    e = w.entry(tmp_path / "tile_c")
    done = []

    def produce():
        for i, n in enumerate((100, 100, 100, 100, 1000)):  # float32: 400 bytes each, then 4000
            e.save(f"block_{i:04d}", {"x": np.zeros(n, np.float32)}, {})
            done.append(i)

    t = threading.Thread(target=produce)
    t.start()
    started.wait(10)
    t.join(0.5)
    assert t.is_alive() and done == [0, 1, 2]  # block 0 being written, 1 and 2 waiting (800 bytes), 3 held back
    gate.set()
    t.join(10)
    assert done == [0, 1, 2, 3, 4]  # the 4000-byte block went through once the queue had emptied
    e.complete({})
    w.flush()
    assert len(list((tmp_path / "tile_c").iterdir())) == 6


def test_the_caller_waits_when_the_queue_is_full(tmp_path, monkeypatch):
    """At most ``pending`` jobs wait (plus the one being written): the blocks held in memory are bounded."""
    gate, started, real = _held_writes(monkeypatch)
    w = CacheWriter(pending=1)
    e = w.entry(tmp_path / "tile_b")
    done = []

    def produce():
        for i in range(3):
            e.save(f"block_{i:04d}", {"x": np.zeros(10, np.float32)}, {})
            done.append(i)

    t = threading.Thread(target=produce)
    t.start()
    started.wait(10)
    t.join(0.5)
    assert t.is_alive() and done == [0, 1]  # block 0 being written, block 1 waiting, block 2 held back
    gate.set()
    t.join(10)
    e.complete({})
    w.flush()
    assert sorted(p.name for p in (tmp_path / "tile_b").iterdir()) == ["block_0000", "block_0001", "block_0002", "meta.json"]


def test_a_failed_write_is_raised_naming_the_entry_and_nothing_half_written_is_left(tmp_path, monkeypatch):
    real, calls = cachewriter.save_stack, []

    def failing(folder, arrays, meta):
        calls.append(folder)
        if len(calls) == 2:
            raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC), str(folder / "x.npy"))
        real(folder, arrays, meta)

    monkeypatch.setattr(cachewriter, "save_stack", failing)
    w = CacheWriter()
    first = w.entry(tmp_path / "tile_1")
    for i in range(2):
        first.save(f"block_{i:04d}", {"x": np.zeros(10, np.float32)}, {})
    first.complete({})
    with pytest.raises(OSError) as err:
        w.flush()
    assert err.value.errno == errno.ENOSPC and err.value.filename == str(tmp_path / "tile_1")  # not the temporary
    assert not (tmp_path / "tile_1").exists() and _leftovers(tmp_path) == []
    w.flush()  # the failure was raised once; the writer goes on
    again = w.entry(tmp_path / "tile_2")
    again.save("block_0000", {"x": np.ones(3, np.float32)}, {})
    again.complete({"ok": 1})
    w.flush()
    assert load_stack(tmp_path / "tile_2")[1] == {"ok": 1}


def test_a_meta_file_that_cannot_be_written_is_raised_naming_the_entry(tmp_path, monkeypatch):
    """A full disk may first show when ``meta.json`` is written or closed, where Python's error names no
    file (found by ``test_faults.test_disk_full_on_a_small_filesystem``): the error still names the entry."""
    from lunaralbedo.io import cache

    real_fdopen = os.fdopen

    class Full:
        def __init__(self, f):
            self.f = f

        def __enter__(self):
            return self

        def __exit__(self, *exc):
            self.f.close()

        def write(self, text):
            raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))  # as a short write reports it: no file name

    monkeypatch.setattr(cache.os, "fdopen", lambda fd, mode: Full(real_fdopen(fd, mode)))
    with pytest.raises(OSError) as err:
        cache.save_meta(tmp_path / "alone", {"a": 1})
    assert err.value.errno == errno.ENOSPC and err.value.filename == str(tmp_path / "alone" / "meta.json")
    assert list((tmp_path / "alone").iterdir()) == []  # its temporary file removed
    w = CacheWriter()
    entry = w.entry(tmp_path / "tile_1")
    entry.save("block_0000", {"x": np.zeros(10, np.float32)}, {})
    entry.complete({})
    with pytest.raises(OSError) as err:
        w.flush()
    assert err.value.errno == errno.ENOSPC and err.value.filename == str(tmp_path / "tile_1")
    assert not (tmp_path / "tile_1").exists() and _leftovers(tmp_path) == []


def test_queued_entries_after_a_failure_are_dropped_and_the_next_call_raises(tmp_path, monkeypatch):
    gate = threading.Event()
    real = cachewriter.save_stack

    def first_fails(folder, arrays, meta):
        gate.wait(10)
        if folder.parent.name.startswith(".tmp-") and "a" in meta:
            raise OSError(errno.EIO, os.strerror(errno.EIO), str(folder))
        real(folder, arrays, meta)

    monkeypatch.setattr(cachewriter, "save_stack", first_fails)
    w = CacheWriter(pending=4)
    a, b = w.entry(tmp_path / "tile_a"), w.entry(tmp_path / "tile_b")
    a.save("block_0000", {"x": np.zeros(3, np.float32)}, {"a": 1})
    a.complete({})
    b.save("block_0000", {"x": np.zeros(3, np.float32)}, {})
    b.complete({})
    gate.set()
    with pytest.raises(OSError, match=re.escape(str(tmp_path / "tile_a"))):
        w.flush()
    assert not (tmp_path / "tile_a").exists() and not (tmp_path / "tile_b").exists() and _leftovers(tmp_path) == []


def test_an_abandoned_entry_leaves_nothing_and_its_late_failure_is_no_error(tmp_path, monkeypatch):
    """A computation that fails abandons its entry: nothing is left, and a write of it that was already
    running when its folder went away (the failed run's clean-up) is not raised into later work."""
    gate, started, real = _held_writes(monkeypatch)
    w = CacheWriter()
    root = tmp_path / "cache"
    root.mkdir()
    e = w.entry(root / "tile_c")
    e.save("block_0000", {"x": np.zeros(3, np.float32)}, {})
    e.save("block_0001", {"x": np.zeros(3, np.float32)}, {})
    started.wait(10)
    e.abandon()  # its computation failed after two blocks, the first being written
    import shutil

    shutil.rmtree(root)  # the failed run's clean-up removes the cache under the running write
    gate.set()
    w.flush()  # no error: the entry was dropped
    assert not root.exists() and _leftovers(tmp_path) == []
    monkeypatch.setattr(cachewriter, "save_stack", real)
    ok = w.entry(tmp_path / "tile_d")
    ok.complete({"ok": 1})
    w.flush()
    assert load_stack(tmp_path / "tile_d")[1] == {"ok": 1}


def test_prepare_in_one_process_returns_before_its_tile_is_written(tmp_path, monkeypatch):
    """``wait=False``: the next tile's computation overlaps this tile's writing; ``flush`` puts it on disk,
    where a second prepare finds it complete (reused)."""
    from lunaralbedo.engine import prepare, tilework
    from lunaralbedo.engine.scene import build_scene
    from lunaralbedo.settings import load_settings
    from lunaralbedo.simulate import SceneSpec, render_scene

    render_scene(tmp_path / "scene", SceneSpec(n_images=3, image_px=60, tile_size=0.25, max_num_iter=2, seed=3))
    sc = build_scene(load_settings(tmp_path / "scene" / "settings.txt"))
    gate = threading.Event()
    real = cachewriter.save_stack
    monkeypatch.setattr(cachewriter, "save_stack", lambda *a: (gate.wait(10), real(*a)))
    cache = tmp_path / "cache"
    cache.mkdir()
    t = max(range(len(sc.tiles)), key=lambda t: len(sc.tile_images[t]))
    first = prepare.prepare_tile(t, scene=sc, cache_root=cache, wait=False)
    folder = tilework.cache_dir(cache, sc, t)
    assert first["reused"] is False and not folder.exists()
    gate.set()
    prepare.WRITER.flush()
    assert prepare.prepare_tile(t, scene=sc, cache_root=cache) == {**first, "reused": True}
    assert _leftovers(cache) == []

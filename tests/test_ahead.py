"""Work one item ahead on a helper thread: the plain loop's results, in order, bounded, failures in their turn."""
from __future__ import annotations

import threading
import time
from concurrent.futures import ThreadPoolExecutor

import pytest

from lunaralbedo.parallel.ahead import ahead, helper


@pytest.fixture
def pool():
    with ThreadPoolExecutor(1) as p:
        yield p


def test_results_come_in_order_and_equal_the_plain_loop(pool):
    def slow_square(x):
        time.sleep(0.002 * (x % 3))  # finishing times out of step with the items
        return x * x

    assert list(ahead(slow_square, range(20), pool)) == [x * x for x in range(20)]
    assert list(ahead(slow_square, range(20), None)) == [x * x for x in range(20)]
    assert list(ahead(slow_square, [], pool)) == []


def test_the_next_item_is_made_while_the_caller_works_on_the_current_one(pool):
    """The helper thread runs item k + 1 while the caller holds item k's result; no further than ``depth``."""
    started, main = [], threading.get_ident()

    def make(x):
        started.append(x)
        assert threading.get_ident() != main
        return x

    seen = []
    for x in ahead(make, range(6), pool):
        time.sleep(0.02)  # the helper has long finished the next item by now, and must not start another
        seen.append((x, sorted(started)))
    assert [x for x, _ in seen] == list(range(6))
    assert [s for _, s in seen[:-1]] == [list(range(x + 2)) for x in range(5)]


def test_items_marked_here_run_in_the_callers_thread_after_the_earlier_ones():
    with ThreadPoolExecutor(1) as pool:
        main, where = threading.get_ident(), {}

        def make(x):
            where[x] = threading.get_ident() == main
            return x

        assert list(ahead(make, range(8), pool, here=lambda x: x % 3 == 0)) == list(range(8))
    assert where == {x: x % 3 == 0 for x in range(8)}


def test_a_failure_is_raised_in_its_items_turn(pool):
    def make(x):
        if x == 3:
            raise ValueError("item 3 is bad")
        return x

    got = []
    with pytest.raises(ValueError, match="item 3 is bad"):
        for x in ahead(make, range(6), pool):
            got.append(x)
    assert got == [0, 1, 2]


def test_a_caller_that_stops_leaves_nothing_running():
    """Closing the generator (the caller's own failure) drops the items not started and waits for the running one."""
    gate, running, done = threading.Event(), threading.Event(), []

    def make(x):
        if x == 1:
            running.set()
            gate.wait(5)
        done.append(x)
        return x

    with ThreadPoolExecutor(1) as pool:
        gen = ahead(make, range(10), pool, depth=2)
        assert next(gen) == 0
        assert running.wait(5)  # item 1 runs on the helper, item 2 waits behind it
        threading.Timer(0.05, gate.set).start()
        gen.close()  # waits for item 1, cancels item 2
        assert done == [0, 1]
        time.sleep(0.05)
        assert done == [0, 1]


def test_the_helpers_are_one_pool_per_name_and_size():
    assert helper("a") is helper("a") and helper("a") is not helper("b") and helper("a") is not helper("a", 2)
    both = threading.Barrier(2, timeout=5)  # two threads: two tasks at once
    assert [f.result() for f in [helper("a", 2).submit(both.wait) for _ in range(2)]] in ([0, 1], [1, 0])
    names = {helper(n).submit(lambda: threading.current_thread().name).result() for n in ("a", "b")}
    assert names == {"lunaralbedo-a-ahead_0", "lunaralbedo-b-ahead_0"}

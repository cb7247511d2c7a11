"""pipeline.Ahead: a generator run one step ahead in a thread keeps order, errors and stops."""

from __future__ import annotations

import threading
import time

import pytest

from ilcforce.pipeline import Ahead, Turns


def test_items_arrive_in_order_and_all_of_them():
    assert list(Ahead(lambda stopping: iter(range(50)))) == list(range(50))


def test_the_producer_runs_ahead_while_the_consumer_works():
    made = []

    def make(stopping):
        for i in range(3):
            made.append(i)
            yield i

    it = iter(Ahead(make))
    assert next(it) == 0
    deadline = time.monotonic() + 5
    while len(made) < 2 and time.monotonic() < deadline:  # item 1 is made before the consumer asks
        time.sleep(0.001)
    assert made[:2] == [0, 1]
    assert list(it) == [1, 2]


def test_a_producer_error_comes_after_every_item_made_before_it():
    def make(stopping):
        yield 1
        yield 2
        raise KeyboardInterrupt  # e.g. a stop request seen between iterations

    got = []
    with pytest.raises(KeyboardInterrupt):
        for item in Ahead(make):
            got.append(item)
    assert got == [1, 2]


def test_a_consumer_that_stops_early_stops_and_joins_the_producer():
    seen_stop = threading.Event()

    def make(stopping):
        i = 0
        while not stopping():
            yield i
            i += 1
        seen_stop.set()

    before = threading.active_count()
    for item in Ahead(make):
        if item == 3:
            break
    assert threading.active_count() == before  # joined, not left running

    def failing_consumer():
        for item in Ahead(make):
            raise OSError("disk full")  # the store's error while writing item 0

    with pytest.raises(OSError, match="disk full"):
        failing_consumer()
    assert threading.active_count() == before


def test_turns_wait_for_the_loop_or_its_end():
    turns = Turns()
    assert turns.wait(0.01) is False and turns.wait_ready(0.01) is False
    turns.enter()
    assert turns.wait(0.01) is True
    turns.leave()
    assert turns.wait(0.01) is False
    turns.ready()
    assert turns.wait_ready(0.01) is True
    later = Turns()
    threading.Timer(0.05, later.over).start()
    assert later.wait(5) is True and later.wait_ready(0) is True
    later.leave()  # a last leave after the end: nobody waits again
    assert later.wait(0) is True

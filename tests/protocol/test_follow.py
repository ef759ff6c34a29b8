"""Following whichever tracker is alive: the first to appear, then the next when it goes."""

from types import SimpleNamespace
from typing import Any

import zenoh

from protocol.net.follow import TrackerFollower, follow_step
from protocol.wire.keys import alive_key, pose_key


class _Network:
    """A stand-in for a session and its liveliness subscriber: the subscriber brings the samples
    queued in ``arriving`` one poll at a time; a ``get`` answers with every token in ``alive``."""

    def __init__(self, alive: list[str], arriving: list[list[tuple[str, bool]]]) -> None:
        self.alive, self.arriving, self.gets = alive, arriving, 0
        self._queue: list[Any] = []

    def liveliness(self) -> Any:
        return self

    def get(self, key: str, timeout: float) -> list[Any]:
        self.gets += 1
        return [SimpleNamespace(ok=SimpleNamespace(key_expr=alive_key(t))) for t in self.alive]

    def poll(self) -> None:
        batch = self.arriving.pop(0) if self.arriving else []
        kinds = {True: zenoh.SampleKind.PUT, False: zenoh.SampleKind.DELETE}
        self._queue = [SimpleNamespace(key_expr=alive_key(t), kind=kinds[a]) for t, a in batch]

    def try_recv(self) -> Any:
        return self._queue.pop(0) if self._queue else None


def test_follows_the_first_alive_and_switches_when_it_goes() -> None:
    f = TrackerFollower()
    assert f.current is None
    assert f.on_token(alive_key("a"), True) and f.current == "a"
    assert not f.on_token(alive_key("b"), True) and f.current == "a"  # a second tracker: keep the first
    assert not f.on_token(alive_key("b"), True)  # a repeated token changes nothing
    assert f.on_token(alive_key("a"), False) and f.current == "b" and f.switches == 1
    assert not f.on_token(alive_key("a"), False)
    assert f.on_token(alive_key("b"), False) and f.current is None
    assert f.on_token(alive_key("c"), True) and f.current == "c" and f.switches == 1  # after none: not a switch
    assert not f.on_token(pose_key("d"), True) and not f.on_token("not a key", True)  # only tokens count
    assert f.current == "c"


def test_trackers_found_together_are_followed_in_the_order_of_their_ids() -> None:
    for order in (["b", "a", "c"], ["c", "a", "b"]):
        f = TrackerFollower()
        assert f.on_tokens([(alive_key(t), True) for t in order]) and f.current == "a"
        assert f.on_tokens([(alive_key("a"), False)]) and f.current == "b"
    g = TrackerFollower()
    assert not g.on_tokens([(alive_key("x"), True), (alive_key("x"), False)]) and g.current is None


def test_a_client_joining_late_follows_the_first_by_id_even_when_history_brings_the_other_first() -> None:
    """The subscriber's history brings 'second' alone in the first poll: the choice waits for the
    network's full answer, which holds 'first' too."""
    net = _Network(alive=["first", "second"], arriving=[[("second", True)], [("first", True)]])
    f, asked = TrackerFollower(), -1e9
    net.poll()
    changed, asked = follow_step(net, net, f, asked, now=0.0)
    assert changed and f.current == "first" and net.gets == 1 and asked == 0.0
    net.poll()
    changed, asked = follow_step(net, net, f, asked, now=0.1)  # followed: history is taken, no get
    assert not changed and f.current == "first" and net.gets == 1
    net.alive = ["second"]
    net.arriving = [[("first", False)]]
    net.poll()
    changed, _ = follow_step(net, net, f, asked, now=0.2)
    assert changed and f.current == "second" and f.switches == 1


def test_a_client_with_nobody_to_follow_asks_the_network_at_most_every_second() -> None:
    net = _Network(alive=[], arriving=[])
    f, asked = TrackerFollower(), -1e9
    for now in (0.0, 0.3, 0.6, 0.9, 1.2):
        net.poll()
        changed, asked = follow_step(net, net, f, asked, now=now)
        assert not changed
    assert net.gets == 2 and asked == 1.2


def test_history_alone_never_chooses_while_the_network_does_not_answer() -> None:
    """A get that answers nothing in time (a loaded machine): the subscriber's history, which
    brought 'second' alone, does not choose; the next answer holds both and 'first' is followed."""
    net = _Network(alive=[], arriving=[[("second", True)], [("first", True)], []])
    f, asked = TrackerFollower(), -1e9
    net.poll()
    changed, asked = follow_step(net, net, f, asked, now=0.0)
    assert not changed and f.current is None and net.gets == 1
    net.alive = ["first", "second"]
    net.poll()
    changed, asked = follow_step(net, net, f, asked, now=0.1)
    assert changed and f.current == "first" and net.gets == 2

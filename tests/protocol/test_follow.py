"""Following whichever tracker is alive: the first to appear, then the next when it goes."""

from protocol.net.follow import TrackerFollower
from protocol.wire.keys import alive_key, pose_key


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

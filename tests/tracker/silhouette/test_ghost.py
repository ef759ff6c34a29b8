"""Ghost detection: a silhouette on the frame's edges is a person; one on the background model's
edges is the hole a person learned into the background left."""

from __future__ import annotations

from dataclasses import replace

import cv2
import numpy as np
import pytest

from tracker_service.silhouette.ghost import GhostParams, across_minus_along, ghost_fraction


def _room(rng: np.random.Generator, texture: float) -> np.ndarray:
    """A (240, 320) brightness image: a smooth gradient plus smoothed random texture of amplitude ``texture``."""
    base = np.linspace(90, 150, 320, dtype=np.float32)[None, :].repeat(240, axis=0)
    noise = cv2.GaussianBlur(rng.normal(0, 1, (240, 320)).astype(np.float32), (0, 0), 1.2)
    return np.clip(base + texture * noise / noise.std(), 0, 255).astype(np.float32)


def _person(cx: int) -> np.ndarray:
    mask = np.zeros((240, 320), np.uint8)
    cv2.ellipse(mask, (cx, 130), (28, 80), 0, 0, 360, 1, -1)
    return mask.astype(bool)


def _bgr(bright: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    img = bright + rng.normal(0, 2.0, bright.shape)
    return np.clip(img, 0, 255).astype(np.uint8)[..., None].repeat(3, axis=2)


@pytest.mark.parametrize("texture", [0.0, 25.0])
def test_a_person_in_an_empty_room_model_is_no_ghost(texture: float, rng: np.random.Generator) -> None:
    room = _room(rng, texture)
    person = _person(160)
    frame = room.copy()
    frame[person] = 40.0  # dark clothes against the room
    assert ghost_fraction(room, _bgr(frame, rng), person) < 0.1


@pytest.mark.parametrize("texture", [0.0, 25.0])
def test_the_hole_left_by_a_person_learned_into_the_background_is_a_ghost(texture: float,
                                                                         rng: np.random.Generator) -> None:
    room = _room(rng, texture)
    was = _person(120)
    model = room.copy()
    model[was] = 40.0  # the background was learned with the person standing there
    now = _person(220)
    frame = room.copy()
    frame[now] = 40.0  # they moved: the room shows where they were
    ghost_only = ghost_fraction(model, _bgr(frame, rng), was)
    both = ghost_fraction(model, _bgr(frame, rng), was | now)
    assert ghost_only > 0.9
    assert 0.3 < both < 0.7  # half of the outline is the ghost's, half the person's


def test_a_room_object_hidden_by_clothes_is_no_ghost_where_the_model_did_not_move(rng: np.random.Generator) -> None:
    """A dark object stands in the room (a plant); a person in a shirt the colour of the wall stands
    in front of it: the shirt shows only over the object, an outline on the model's edges -- the
    ghost's signature. Two facts tell them apart: a person learned into the background moved while
    it was learned (their outline spread), the object did not; and a person who stood still then
    moved away leaves a ghost outside the outline of where they are now, the object's piece of
    shirt lies within it."""
    room = _room(rng, 0.0)
    body = _person(160)
    rows = np.arange(240)[:, None]
    head, legs = body & (rows < 80), body & (rows >= 160)
    plant = np.zeros((240, 320), np.uint8)
    cv2.ellipse(plant, (160, 120), (18, 30), 0, 0, 360, 1, -1)
    plant = plant.astype(bool)
    model = room.copy()
    model[plant] = 40.0
    frame = room.copy()  # the shirt over the plant looks like the wall
    frame[head | legs] = 40.0
    mask = head | legs | plant
    still = np.full((240, 320), 2.0, np.float32)  # the camera's noise everywhere: nothing moved
    assert ghost_fraction(model, _bgr(frame, rng), mask) > 0.3  # by edges alone: a ghost
    assert ghost_fraction(model, _bgr(frame, rng), mask, background_std=still) < 0.05
    # a person learned there swayed while the room was learned: their outline's spread is high
    m = plant.astype(np.uint8)
    swayed = still.copy()
    swayed[cv2.dilate(m, np.ones((5, 5), np.uint8)) > cv2.erode(m, np.ones((5, 5), np.uint8))] = 15.0
    assert ghost_fraction(model, _bgr(frame, rng), mask, background_std=swayed) > 0.3
    # one who stood still and stepped aside: their ghost lies apart from them
    was, now = _person(100), _person(220)
    model2, frame2 = room.copy(), room.copy()
    model2[was], frame2[now] = 40.0, 40.0
    assert ghost_fraction(model2, _bgr(frame2, rng), was | now, background_std=still) > 0.3
    off = GhostParams(motion_factor=0.0)
    assert ghost_fraction(model, _bgr(frame, rng), mask, off, background_std=still) > 0.3


def test_a_notch_of_camouflage_beside_the_persons_votes_is_no_ghost(rng: np.random.Generator) -> None:
    """The shirt's right half is the colour of the wall and shows only over a dark object behind it:
    that piece of silhouette bulges a few pixels out of the hull of the outline voting *person* (a
    blurred, noisy camera leaves such sparse votes), bounded by the object's edge. A short stretch
    of contour between two person votes, close to their hull, is a notch in the person, not a ghost
    left apart; a person who stepped away, touching their ghost or apart from it, is still seen."""
    room = _room(rng, 0.0)
    body = _person(160)
    rows, cols = np.arange(240)[:, None], np.arange(320)[None, :]
    torso = body & (rows >= 60) & (rows < 185)
    plant = np.zeros((240, 320), np.uint8)
    cv2.ellipse(plant, (173, 122), (12, 11), 0, 0, 360, 1, -1)
    model = room.copy()
    model[plant > 0] = 40.0
    frame = room.copy()
    dark = body & ~(torso & (cols >= 162))  # head, legs and the shirt's left half
    frame[dark] = 40.0
    mask = dark | (torso & (plant > 0))
    still = np.full((240, 320), 2.0, np.float32)
    p = GhostParams()
    assert ghost_fraction(model, _bgr(frame, rng), mask, replace(p, notch_margin=0.0),
                          background_std=still) > p.moved_threshold  # the hull alone: a ghost
    assert ghost_fraction(model, _bgr(frame, rng), mask, p, background_std=still) < 0.5 * p.moved_threshold
    was = _person(100)
    for cx in (150, 220):  # touching the ghost, then apart from it
        model2, frame2 = room.copy(), room.copy()
        model2[was], frame2[_person(cx)] = 40.0, 40.0
        assert ghost_fraction(model2, _bgr(frame2, rng), was | _person(cx), p, background_std=still) > 0.3


def test_a_small_or_empty_silhouette_is_not_judged(rng: np.random.Generator) -> None:
    room = _room(rng, 10.0)
    tiny = np.zeros((240, 320), bool)
    tiny[100:103, 100:103] = True
    assert ghost_fraction(room, _bgr(room, rng), tiny) == 0.0
    assert ghost_fraction(room, _bgr(room, rng), np.zeros((240, 320), bool)) == 0.0


def test_texture_cancels_and_an_edge_along_the_outline_counts(rng: np.random.Generator) -> None:
    """The gradient across the outline minus along it: about 0 for isotropic texture, large for the
    outline's own edge."""
    person = _person(160).astype(np.uint8)
    outline = person > cv2.erode(person, np.ones((3, 3), np.uint8))
    mx = cv2.Sobel(cv2.GaussianBlur(person.astype(np.float32), (0, 0), 1.5), cv2.CV_32F, 1, 0, ksize=3)
    my = cv2.Sobel(cv2.GaussianBlur(person.astype(np.float32), (0, 0), 1.5), cv2.CV_32F, 0, 1, ksize=3)
    n = np.hypot(mx[outline], my[outline]) + 1e-9
    nx, ny = mx[outline] / n, my[outline] / n
    edge = np.where(person > 0, 40.0, 140.0).astype(np.float32)
    texture = _room(rng, 40.0) - _room(np.random.default_rng(0), 0.0)
    e_edge = across_minus_along(edge, outline, nx, ny, 1.0)
    e_texture = across_minus_along(texture, outline, nx, ny, 1.0)
    assert e_edge.shape == e_texture.shape == (int(outline.sum()),)
    assert np.median(e_edge) > 100 and abs(float(e_texture.mean())) < 0.15 * float(e_edge.mean())


def test_params_are_ordered() -> None:
    p = GhostParams()
    assert 0 < p.threshold_relearned <= p.threshold_start <= p.threshold < 1 and p.frames >= 1


def test_the_frames_smoothing_folds_into_the_gradients(rng: np.random.Generator) -> None:
    """A noisy camera's smoothing given as ``frame_sigma`` reads as the frame smoothed first."""
    from tracker_service.silhouette.background import smoothed

    room = _room(rng, 25.0)
    was, now = _person(120), _person(220)
    model = room.copy()
    model[was] = 40.0
    frame = room.copy()
    frame[now] = 40.0
    img = _bgr(frame + rng.normal(0, 6.0, frame.shape), rng)
    for sigma in (1.0, 1.5):
        first = ghost_fraction(model, smoothed(img, sigma), was | now)
        folded = ghost_fraction(model, img, was | now, frame_sigma=sigma)
        assert abs(first - folded) < 0.03

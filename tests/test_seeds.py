"""errormap.seeds: sub-streams are children of SeedSequence(seed), reproducible and distinct."""
import numpy as np

from errormap.seeds import spawn_rngs, spawn_seeds


def test_children_are_reproducible_and_distinct():
    a = [g.random(4) for g in spawn_rngs(3, 3)]
    b = [g.random(4) for g in spawn_rngs(3, 3)]
    assert all(np.array_equal(x, y) for x, y in zip(a, b))
    assert not np.array_equal(a[0], a[1]) and not np.array_equal(a[1], a[2])
    # a child is not the parent's own stream, nor the neighbouring seed's
    assert not np.array_equal(a[0], np.random.default_rng(3).random(4))
    assert not np.array_equal(a[0], np.random.default_rng(4).random(4))


def test_children_match_numpy_spawn():
    kids = spawn_seeds(11, 2)
    ref = np.random.SeedSequence(11).spawn(2)
    assert [k.spawn_key for k in kids] == [r.spawn_key for r in ref]
    assert np.array_equal(kids[1].generate_state(4), ref[1].generate_state(4))

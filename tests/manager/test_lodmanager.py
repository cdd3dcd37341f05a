"""The LODManager's algorithm (Gumbau et al., §4), GL-free."""

from __future__ import annotations

import numpy as np
import pytest

from lodsprite.errors import InputError
from lodsprite.manager.core import (
    Feedback,
    LodManager,
    active_list,
    desired_lod,
    finer_near,
    similar,
    slot_of,
)


def test_slots_and_eq1_similarity_linear():
    # N_T = 2: [0, 0.5) is slot 0 and [0.5, 1] slot 1 (the paper's example)
    assert slot_of([0.0, 0.49, 0.5, 1.0], 2).tolist() == [0, 0, 1, 1]
    assert slot_of(0.999, 10) == 9 and slot_of(1.0, 10) == 9
    assert similar(0.31, 0.39, 10) and not similar(0.39, 0.41, 10)


def test_non_linear_snapshots_are_finer_near_one():
    lods = np.linspace(0, 1, 1001)
    s = slot_of(lods, 8, finer_near)
    widths = np.array([np.ptp(lods[s == k]) for k in range(8)])
    assert (np.diff(widths) < 0).all()          # each slot narrower than the one before
    assert similar(0.1, 0.3, 8, finer_near) and not similar(0.9, 0.95, 8, finer_near)


def test_desired_lod_is_linear_in_distance_clamped_and_bent():
    d = np.array([0.0, 5.0, 55.0, 105.0, 500.0])
    np.testing.assert_allclose(desired_lod(d, 5.0, 105.0), [1, 1, 0.5, 0, 0])
    np.testing.assert_allclose(desired_lod(d, 5.0, 105.0, 2.0), [1, 1, 0.25, 0, 0])


def test_feedback_bends_coarser_under_target_and_finer_over_it():
    slow = Feedback(target_fps=30.0)
    for _ in range(5):
        slow.observe(50.0)                       # 20 fps: under the target
    fast = Feedback(target_fps=30.0)
    for _ in range(5):
        fast.observe(20.0)                       # 50 fps: over it
    lod = np.array([0.3, 0.6, 0.9])
    assert slow.exponent > 1 > fast.exponent
    assert (desired_lod(40.0, 5, 105, slow.exponent) < desired_lod(40.0, 5, 105)).all()
    assert (desired_lod(40.0, 5, 105, fast.exponent) > desired_lod(40.0, 5, 105)).all()
    assert (lod ** slow.exponent < lod).all()
    steady = Feedback(target_fps=30.0)
    steady.observe(1e3 / 30.0)
    assert steady.exponent == pytest.approx(1.0)
    with pytest.raises(InputError):
        Feedback(target_fps=0.0)


def test_active_list_takes_the_largest_changes_and_penalises_the_unseen():
    desired = np.array([0.9, 0.9, 0.55, 0.12, 0.8])
    current = np.array([0.1, 0.1, 0.5, 0.1, 0.0])
    visible = np.array([True, False, True, True, True])
    # 2 and 3 are similar (no change needed); 1 is outside the frustum: 0.8 * 0.25 = 0.2
    a = active_list(desired, current, visible, n_active=2, n_slots=10)
    assert a.tolist() == [4, 0] or a.tolist() == [0, 4]
    assert active_list(desired, current, visible, 3, 10).tolist()[-1] == 1
    # unseen but big enough still gets in: near objects about to enter the view
    a = active_list(np.array([1.0, 0.2]), np.array([0.0, 0.0]), np.array([False, True]), 1,
                    10)
    assert a.tolist() == [0]


def test_section_4_1_on_a_hand_made_sequence():
    # five objects of one type, N_T = 4 (slots [0, .25) [.25, .5) [.5, .75) [.75, 1])
    m = LodManager(np.zeros(5, int), n_types=1, n_slots=4, base_lod=0.0)
    assert m.slots.tolist() == [[0, -1, -1, -1]]          # the base LOD, buffer 0
    everyone = np.arange(5)
    # object 0 wants 0.6: nothing in slot 2, it extracts into its own buffer 1
    orders = m.update(everyone, np.array([0.6, 0.1, 0.1, 0.1, 0.1]))
    assert [(o.obj, o.buffer, o.lod) for o in orders] == [(0, 1, 0.6)]
    assert m.slots.tolist() == [[0, -1, 1, -1]] and m.using.tolist() == [1, 0, 0, 0, 0]
    # objects 1 and 2 want 0.7 and 0.55: similar to 0.6, both borrow buffer 1; object 3
    # wants 0.9: extracts its own (buffer 2, slot 3); object 4 stays (0.1 is similar to 0)
    orders = m.update(everyone, np.array([0.6, 0.7, 0.55, 0.9, 0.1]))
    assert [(o.obj, o.buffer) for o in orders] == [(3, 2)]
    assert m.using.tolist() == [1, 1, 1, 2, 0] and m.lod[1] == m.lod[2] == 0.6
    assert m.slots.tolist() == [[0, -1, 1, 2]]
    assert m.extractions == 2 and m.borrows == 2
    # object 3 falls back to 0.05: it borrows the base LOD, and (2(d) ii) leaves D_T
    orders = m.update(everyone, np.array([0.6, 0.7, 0.55, 0.05, 0.1]))
    assert orders == [] and m.using[3] == 0 and m.slots.tolist() == [[0, -1, 1, -1]]


def test_a_borrower_that_changes_lod_updates_its_own_buffer_not_the_borrowed_one():
    m = LodManager(np.zeros(3, int), n_types=1, n_slots=4)
    m.update(np.arange(3), np.array([0.6, 0.6, 0.0]))     # 0 extracts (buffer 1), 1 borrows
    assert m.using.tolist() == [1, 1, 0] and m.own.tolist() == [1, -1, -1]
    orders = m.update(np.array([1]), np.array([0.6, 0.3, 0.0]))
    # the borrower extracts into a buffer of its own; the lender's buffer 1 keeps 0.6
    assert [(o.obj, o.buffer) for o in orders] == [(1, 2)]
    assert m.buffer_lod[1] == 0.6 and m.using[0] == 1 and m.own[1] == 2
    # and a lender whose buffer is borrowed takes a fresh one when it changes itself
    m.update(np.array([1]), np.array([0.6, 0.6, 0.0]))    # 1 borrows 0's again
    orders = m.update(np.array([0]), np.array([0.95, 0.6, 0.0]))
    assert orders[0].buffer not in (1,) and m.using[1] == 1 and m.buffer_lod[1] == 0.6


def test_without_sharing_every_change_extracts():
    m = LodManager(np.zeros(4, int), n_types=1, n_slots=4, share=False)
    orders = m.update(np.arange(4), np.array([0.6, 0.6, 0.6, 0.0]))
    assert len(orders) == 3 and len(set(o.buffer for o in orders)) == 3
    assert (m.slots == -1).sum() == 3                      # nothing registered but the base


def test_impossible_slots_are_refused():
    with pytest.raises(InputError, match="--slots"):
        LodManager(np.zeros(2, int), 1, 0)

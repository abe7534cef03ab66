"""The audit's scoring on small recordings whose phases are known: a profile learned from four labelled
recordings of three phases (reach, carry, place: 5, 3 and 8 s at 10 Hz, their lengths varying as a person's do), then
recordings changed where a real one goes wrong, decoded as they are (their labels as the path). The generated arm's
failures through a fitted model are tests/cli/test_audit_cli.py's."""

from __future__ import annotations

import numpy as np
import pytest

from mlnseq.auditing import scoring
from mlnseq.auditing.chains import Decoded
from mlnseq.auditing.profile import Profile, learn
from mlnseq.auditing.scoring import Kind
from mlnseq.catalog.errors import BadInput

RATE = 10.0
CLASSES = ["reach", "carry", "place"]
COLUMNS = [("load", "high"), ("load", "low"), ("moving", "yes")]
REACH, CARRY, PLACE = range(3)


def recording(lengths: list[tuple[int, int]], rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    """Labels and predicates of phases (phase, frames): the load high throughout carry, low elsewhere, and a column
    true at random."""
    labels = np.concatenate([np.full(n, phase) for phase, n in lengths])
    evidence = np.zeros((len(labels), 3), dtype=bool)
    evidence[:, 0] = labels == CARRY
    evidence[:, 1] = labels != CARRY
    evidence[:, 2] = rng.random(len(labels)) < 0.5
    return labels, evidence


@pytest.fixture(scope="module")
def profile() -> Profile:
    rng = np.random.default_rng(0)
    parts = [recording([(REACH, 50 + d), (CARRY, 30 + d // 2), (PLACE, 80 - d)], rng) for d in (-6, -2, 3, 7)]
    labels = np.concatenate([p[0] for p in parts])
    episodes = np.concatenate([np.full(len(p[0]), k) for k, p in enumerate(parts)])
    return learn(labels, episodes, np.concatenate([p[1] for p in parts]), CLASSES, COLUMNS, RATE)


def audited(profile: Profile, lengths: list[tuple[int, int]], edit=None) -> scoring.Audited:
    labels, evidence = recording(lengths, np.random.default_rng(1))
    if edit is not None:
        edit(labels, evidence)
    return scoring.audit(profile, Decoded(labels, evidence))


def test_the_profile_holds_the_labelled_order_durations_and_rules(profile):
    assert profile.orders == ((REACH, CARRY, PLACE),) * 4
    assert profile.log_seconds[CARRY] == pytest.approx(np.log([2.7, 2.9, 3.1, 3.3]).mean())
    assert {(r.phase, COLUMNS[r.column], r.holds) for r in profile.rules} == {
        (CARRY, ("load", "high"), True), (CARRY, ("load", "low"), False),
        (REACH, ("load", "low"), True), (REACH, ("load", "high"), False),
        (PLACE, ("load", "low"), True), (PLACE, ("load", "high"), False)}
    assert Profile.read(profile.to_json(), "m.mlnseq") == profile


def test_a_recording_like_the_labelled_ones_is_ok_flicker_and_all(profile):
    def flicker(labels, evidence):
        labels[60:63] = REACH  # three frames of the decoder's flicker within carry
    result = audited(profile, [(REACH, 52), (CARRY, 31), (PLACE, 78)], flicker)
    assert not result.suspect and result.score < 0.5, result.reasons


def test_a_slower_recording_is_not_a_failure_but_a_pause_in_one_phase_is(profile):
    slow = audited(profile, [(REACH, 85), (CARRY, 51), (PLACE, 136)])
    assert not slow.suspect and slow.pace == pytest.approx(np.log(1.7), abs=0.05)
    paused = audited(profile, [(REACH, 50), (CARRY, 90), (PLACE, 80)])
    first = paused.reasons[0]
    assert paused.suspect and first.kind is Kind.LONG and first.phase == CARRY
    assert first.text.startswith("carry lasts 9.0 s, 3.") and (first.start, first.stop) == (50, 140)


def test_a_phase_again_names_the_phase_under_way(profile):
    result = audited(profile, [(REACH, 50), (CARRY, 30), (REACH, 30), (CARRY, 30), (PLACE, 80)])
    first = result.reasons[0]
    assert result.suspect and first.kind is Kind.REPEATED and first.phase == CARRY
    assert first.text == "reach again after carry" and first.start == 80


def test_a_recording_cut_short_ends_during_its_last_phase(profile):
    result = audited(profile, [(REACH, 50), (CARRY, 30)])
    missing = [r for r in result.reasons if r.kind is Kind.MISSING]
    assert result.suspect and missing[0].text == "ends during carry, without place"


def test_a_rule_broken_for_a_stretch_says_the_value_it_had(profile):
    def dropped(labels, evidence):  # the load gone for 1.2 s of carry (frames 50-79; its 3 at each end not judged)
        evidence[62:74, 0], evidence[62:74, 1] = False, True
    result = audited(profile, [(REACH, 50), (CARRY, 30), (PLACE, 80)], dropped)
    rule = next(r for r in result.reasons if r.kind is Kind.RULE)
    assert result.suspect and rule.phase == CARRY and (rule.start, rule.stop) == (62, 74)
    assert rule.text == "carry with load low for 1.2 s, where every labelled carry has load high"
    edge = audited(profile, [(REACH, 50), (CARRY, 30), (PLACE, 80)],
                   lambda labels, evidence: evidence.__setitem__((slice(77, 80), 0), False))
    assert not edge.suspect


def test_a_malformed_profile_is_one_line(profile):
    with pytest.raises(BadInput, match=r"^m\.mlnseq: its audit profile is not one this mlnseq reads .*export"):
        Profile.read(profile.to_json().replace(b'"rate": 10.0', b'"rate": -1'), "m.mlnseq")
    with pytest.raises(BadInput, match="not one this mlnseq reads"):
        Profile.read(b"[1, 2", "m.mlnseq")


def test_a_stretch_the_chain_finds_unlikely_is_listed_from_its_first_unlikely_step_but_never_decides(profile):
    from dataclasses import replace

    chained = replace(profile, chain=-1.0)
    labels, evidence = recording([(REACH, 50), (CARRY, 30), (PLACE, 80)], np.random.default_rng(1))
    likelihood = np.full(len(labels), -0.01)
    likelihood[95:115] = -3.0  # 2 s of unlikely steps within place, long past the chain's least allowance
    result = scoring.audit(chained, Decoded(labels, evidence, likelihood))
    (reason,) = result.reasons
    assert reason.kind is Kind.CHAIN and reason.phase == PLACE and reason.start == 95
    assert reason.measure / scoring.allowance(chained, scoring.Check.CHAIN) > 1  # measured far past its allowance
    assert reason.severity == scoring.SHOWN and result.score == scoring.SHOWN and not result.suspect


def test_allowances_leave_out_one_held_out_recording_decoded_badly():
    from mlnseq.auditing import calibration
    from mlnseq.auditing.profile import Calibration

    few = [{"order": 0.0, "duration": 2.0}, {"order": 6.5, "duration": 3.4}, {"duration": 1.0}]
    assert calibration._allowances(few)["order"] == pytest.approx(1.25 * 6.5)  # four or fewer: the highest counts
    many = few + [{"duration": 1.6}, {"duration": 0.4}, {"order": 0.5}]
    allowed = calibration._allowances(many)
    assert allowed["order"] == pytest.approx(1.0) and allowed["duration"] == pytest.approx(3.0)  # the least
    assert calibration._floor([-0.1, -0.3, -0.12, -0.11, -0.13]) == pytest.approx(-0.13 - calibration.CHAIN_MARGIN)
    assert Calibration(accuracy=0.74).trusted is False and Calibration(accuracy=0.97).trusted
    assert Calibration().trusted  # a profile from before audit measured its decoding: nothing said

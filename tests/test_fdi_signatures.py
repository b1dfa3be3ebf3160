"""Fault signature tables (issue 4, section 3): the signs the physics dictates."""

import pytest

from fdi.signatures import signature_table, write_signatures
from sam import load_plant


@pytest.fixture(scope="module")
def rows():
    return signature_table(load_plant())


def _steady_moving(rows, fault, motion=None):
    return [r for r in rows if r["fault"] == fault and r["phase"] == "steady" and r["stalled"] == "no"
            and (motion is None or r["motion"] == motion)]


def test_offset_signs_follow_the_flow_it_adds(rows):
    """A positive offset opens P->A and B->T at zero command: every moving piston ends up
    faster towards extension (d_v > 0: extension faster, retraction slower); a negative one
    the other way."""
    for fault, sign in (("offset+", 1), ("offset-", -1)):
        sel = _steady_moving(rows, fault)
        assert len(sel) >= 5
        assert all(sign * r["d_v_mm_s"] > 0.5 for r in sel), [(r["motion"], r["load_kg"], r["d_v_mm_s"]) for r in sel]


def test_external_leak_signs_follow_continuity(rows):
    """Oil lost from A slows an extension (A is fed) and speeds a retraction (A drains), so
    d_v < 0 in both; oil lost from B does the opposite (d_v > 0 in both); and a leak lowers the
    pressure of the chamber it leaks from."""
    for fault, sign in (("K_extA", -1), ("K_extB", 1)):
        sel = _steady_moving(rows, fault)
        assert all(sign * r["d_v_mm_s"] > 0.2 for r in sel), [(r["motion"], r["load_kg"], r["d_v_mm_s"]) for r in sel]
    assert all(r["d_pA_kPa"] < -50 for r in _steady_moving(rows, "K_extA"))
    assert all(r["d_pB_kPa"] < -50 for r in _steady_moving(rows, "K_extB"))


def test_the_leak_present_leads_the_filter_estimates(rows):
    """In steady motion the filter's estimate of the leak that is there exceeds its estimates
    of the other two (1 L/min faults; 2 s after the onset)."""
    leaks = ("K_int", "K_extA", "K_extB")
    for fault in leaks:
        for r in _steady_moving(rows, fault):
            own = r[f"est_{fault}_Lpm"]
            assert own > 0.5 and all(own > r[f"est_{o}_Lpm"] for o in leaks if o != fault), r


def test_stall_is_flagged(rows):
    """On the former default plant 1.5 V cannot extend the piston against 800 kg (it lifts 719 kg
    at most, docs/model.md): those rows are marked stalled, and no other row is. The default plant
    lifts 800 kg: no row is."""
    from stall_cases import FORMER_PLANT

    former = signature_table(load_plant(FORMER_PLANT))
    assert {(r["motion"], r["load_kg"]) for r in former if r["stalled"] == "yes"} == {("extend", 800.0)}
    assert not any(r["stalled"] == "yes" for r in rows)


def test_written_files(rows, tmp_path):
    paths = write_signatures(rows, tmp_path)
    assert [p.name for p in paths] == ["signatures.csv", "signatures.md", "signatures.png"]
    text = (tmp_path / "signatures.md").read_text()
    assert "stalled" in text and text.count("\n| ") == len(rows) + 1


def test_figure_has_a_titled_map_per_motion_and_phase(tmp_path, saved_figures):
    """signatures.png: one heat map per motion and phase (not one of 60 rows), titled, its rows
    the faults in words by load (stalled ones marked), each cell the effect over the largest
    |effect| on its quantity in the whole table (hand-made, seeded rows)."""
    import numpy as np

    from fdi.signatures import FAULTS, LOADS, MOTIONS, PHASES, QUANTITIES

    rng = np.random.default_rng(3)
    table = [{"fault": f, "motion": mo, "load_kg": m, "phase": ph, "v_healthy_mm_s": 1.0,
              "stalled": "yes" if (mo, m) == ("extend", 800.0) else "no",
              **{q: float(rng.normal(0, 10)) for q in QUANTITIES}}
             for mo in MOTIONS for m in LOADS for f in FAULTS for ph in PHASES]
    write_signatures(table, tmp_path)
    fig, = saved_figures
    maps = {ax.get_title(): ax for ax in fig.axes if ax.images}
    assert set(maps) == {"extend, transient (first 0.3 s after the fault)", "extend, steady (last 0.5 s)",
                         "retract, transient (first 0.3 s after the fault)", "retract, steady (last 0.5 s)"}
    scale = np.abs([[r[q] for q in QUANTITIES] for r in table]).max(axis=0)
    ax = maps["extend, steady (last 0.5 s)"]
    mine = [r for r in table if (r["motion"], r["phase"]) == ("extend", "steady")]
    mine.sort(key=lambda r: (list(FAULTS).index(r["fault"]), r["load_kg"]))
    np.testing.assert_allclose(ax.images[0].get_array(), [[r[q] for q in QUANTITIES] for r in mine] / scale)
    labels = [tx.get_text() for tx in ax.get_yticklabels()]
    assert labels[:3] == ["internal leak, 0 kg", "internal leak, 494 kg", "internal leak, 800 kg (stalled)"]
    assert [tx.get_text() for tx in ax.get_xticklabels()][:3] == ["p_A [kPa]", "p_B [kPa]", "velocity [mm/s]"]
    assert min(tx.get_fontsize() for tx in ax.get_yticklabels() + ax.get_xticklabels()) >= 10

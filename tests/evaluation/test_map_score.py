import json

import numpy as np
import pytest

from tractionecu.evaluation.map_score import map_scorecard, track_mask, write_map_scorecard
from tractionecu.mapping.store import MapStore

from map_synth import ORIGIN, SOIL_A, SOIL_RHO, fill_store, passes, soil_xy


def truth_local():
    def soil(x, y):
        return soil_xy(x, y)

    def values(x, y):
        s = soil_xy(x, y)
        return {"a": np.vectorize(SOIL_A.get)(s), "rho_s": np.vectorize(SOIL_RHO.get)(s)}

    return soil, values


@pytest.fixture(scope="module")
def noisy_map(tmp_path_factory):
    d = tmp_path_factory.mktemp("score")
    st = MapStore(d, *ORIGIN)
    x, y = passes()
    fill_store(st, x, y, np.random.default_rng(17))
    st.close()
    return d, x, y


def test_scorecard_on_a_well_mapped_field(noisy_map):
    d, x, y = noisy_map
    soil, values = truth_local()
    card = map_scorecard(d, soil, values, np.column_stack([x, y]), soil_a=SOIL_A, truth_frame="local")
    assert card["map_soil_accuracy"] >= 0.95
    # the filled-map error is dominated by blending across soil boundaries
    assert card["map_a_rmse"] < 0.035 and card["map_rho_s_rmse"] < 0.009
    # measured cells hold ~2 samples (0.25 m steps, 0.5 m cells): rmse ≈ σ/√2
    assert card["map_a_rmse_measured"] == pytest.approx(0.02 / np.sqrt(2), rel=0.25)
    assert card["map_rho_s_rmse_measured"] == pytest.approx(0.004 / np.sqrt(2), rel=0.25)
    assert card["map_cells_scored"] > card["map_cells_measured"] > 0
    assert json.loads(write_map_scorecard(d, card).read_text()) == card


def test_scorecard_frames_and_track_sources_agree(noisy_map):
    d, x, y = noisy_map
    store = MapStore.open(d, read_only=True)
    soil, values = truth_local()

    def soil_ll(lat, lon):
        return soil(*store.to_local(lat, lon))

    def values_ll(lat, lon):
        v = values(*store.to_local(lat, lon))
        return v["a"], v["rho_s"]  # the tuple form is accepted too

    lat, lon = store.to_latlon(x, y)
    a = map_scorecard(d, soil, values, np.column_stack([x, y]), soil_a=SOIL_A, truth_frame="local")
    b = map_scorecard(store, soil_ll, values_ll, track_latlon=np.column_stack([lat, lon]), soil_a=SOIL_A)
    c = map_scorecard(d, soil_ll, values_ll, soil_a=SOIL_A)  # track recorded in the store
    for key in ("map_soil_accuracy", "map_a_rmse", "map_rho_s_rmse", "map_cells_scored"):
        assert a[key] == pytest.approx(b[key], rel=1e-9) and a[key] == pytest.approx(c[key], rel=1e-9)


def test_wrong_classes_score_zero_and_radius_limits_cells(noisy_map):
    d, x, y = noisy_map
    _, values = truth_local()
    card = map_scorecard(d, lambda p, q: np.full(np.shape(p), 7), values, np.column_stack([x, y]),
                         soil_a=SOIL_A, truth_frame="local")
    assert card["map_soil_accuracy"] == 0.0
    soil, _ = truth_local()
    near = map_scorecard(d, soil, values, np.column_stack([x, y]), soil_a=SOIL_A, truth_frame="local",
                         radius_m=1.0)
    far = map_scorecard(d, soil, values, np.column_stack([x, y]), soil_a=SOIL_A, truth_frame="local")
    assert 0 < near["map_cells_scored"] < far["map_cells_scored"]
    # a short piece of track scores only cells near it
    part = map_scorecard(d, soil, values, np.column_stack([x[:40], y[:40]]), soil_a=SOIL_A, truth_frame="local")
    assert 0 < part["map_cells_scored"] < far["map_cells_scored"] / 5


def test_empty_map_scores_none(tmp_path):
    MapStore(tmp_path, *ORIGIN).close()
    soil, values = truth_local()
    card = map_scorecard(tmp_path, soil, values, np.zeros((0, 2)), soil_a=SOIL_A, truth_frame="local")
    assert card["map_soil_accuracy"] is None and card["map_cells_scored"] == 0


def test_track_mask_draws_segments_and_skips_gaps():
    m = track_mask((10, 40), 0.0, 0.0, 0.5, [[0.1, 0.1], [5.1, 0.1], [19.9, 4.9]], max_gap_m=10.0)
    assert m[0, :11].all()          # the 5 m segment is drawn cell by cell
    assert m.sum() == 11 + 1        # the 15 m jump is a gap: only its end point
    assert m[9, 39]

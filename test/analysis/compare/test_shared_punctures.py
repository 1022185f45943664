"""Punctures on real-shaped layered curves: a pre-drop, partial drops and a rounded peak, told
apart (force_events) and shared across repeats (shared_punctures), and the comparison that does
not charge a simulated puncture within the repeats' spread as a miss.

The truth: curves drawn from a formula whose every event is known (analysis.synthetic_curves),
with 5 mN of noise and each repeat's depths and peaks jittered as a phantom's are."""
import numpy as np
import pytest

from tissue_sim_ros.analysis.compare.force_events import PRE_DROP, PUNCTURE, detect_drops, detect_punctures
from tissue_sim_ros.analysis.compare.shared_punctures import pair_punctures, shared_punctures
from tissue_sim_ros.analysis.synthetic_curves import layered_curve


def repeats(seed, count=5, **shape):
    """``count`` repeats of the two-layer shape, each with its own depths (0.5 mm s.d.), peaks
    (0.2 N s.d.) and pre-drop depth; the truth per repeat."""
    rng = np.random.default_rng(seed)
    curves = []
    for _ in range(count):
        depths = (0.0135 + rng.normal(0, 5e-4), 0.020 + rng.normal(0, 5e-4))
        peaks = (4.0 + rng.normal(0, 0.2), 5.0 + rng.normal(0, 0.2))
        pre_drop = 0.0094 + rng.normal(0, 3e-4)
        curves.append(layered_curve(rng, **dict(dict(depths_m=depths, peaks_n=peaks, pre_drop_m=pre_drop), **shape)))
    return curves


def since_contact(curve):
    return curve.travel_m - curve.gap_m


def rounded_peak_depth(curve):
    """Where the noiseless rounded second peak is highest (the formula's own maximum)."""
    x = since_contact(curve)
    inserting = np.arange(len(x)) < np.argmax(x)
    window = inserting & (x > curve.puncture_depths_m[1] - 0.002) & (x < curve.puncture_depths_m[1] + 0.001)
    return float(x[window][np.argmax(curve.noiseless_n[window])])


def test_a_pre_drop_is_told_from_a_puncture_and_a_rounded_peak_is_found():
    """A pre-drop of 0.8 N at 2.4 N (a third of the force, well past the 15 % a puncture needs)
    that the same loading regains at once is a pre-drop; the partial drop (4 -> 2 N) and the
    rounded second peak (its fall spread over 1.5 mm) are punctures, at their depths."""
    for curve in repeats(1, pre_drop_n=0.8):
        drops = detect_drops(since_contact(curve), curve.force_n)
        kinds = [(d.kind, round(d.travel_m * 1e3, 1)) for d in drops]
        print(kinds)
        pre = [d for d in drops if d.kind == PRE_DROP]
        punctures = [d for d in drops if d.kind == PUNCTURE]
        assert len(pre) == 1 and abs(pre[0].travel_m - curve.pre_drop_m) < 2e-4
        assert pre[0].drop_n > 0.15 * pre[0].force_n                    # a puncture's size, not its shape
        assert len(punctures) == 2
        assert abs(punctures[0].travel_m - curve.puncture_depths_m[0]) < 2e-4
        assert punctures[0].force_n == pytest.approx(curve.puncture_forces_n[0], abs=0.05)
        assert punctures[0].drop_n == pytest.approx(0.5 * curve.puncture_forces_n[0], abs=0.1)   # partial
        assert abs(punctures[1].travel_m - rounded_peak_depth(curve)) < 3e-4
        assert punctures[1].fall_m > 5e-4                                 # rounded: it falls over travel


def test_the_old_window_missed_the_rounded_peak_and_took_the_pre_drop():
    """What the detector did before: a 1.5 mm window after the peak finds only part of a rounded
    fall (under the 15 % a puncture needs) and any drop is a puncture (the pre-drop among them)."""
    curve = repeats(2, count=1, pre_drop_n=0.8, rounding_m=(0.0, 0.004))[0]
    narrow = detect_drops(since_contact(curve), curve.force_n, window_m=0.0015)
    print([(d.kind, round(d.travel_m * 1e3, 1), round(d.drop_n, 2)) for d in narrow])
    assert not any(abs(d.travel_m - curve.puncture_depths_m[1]) < 0.003 for d in narrow)
    wide = detect_punctures(since_contact(curve), curve.force_n)
    assert len(wide) == 2 and wide[0].travel_m > curve.pre_drop_m + 0.002


def test_the_repeats_share_two_layers_with_their_spread_and_not_the_pre_drops():
    """Five repeats: two layers, each depth's mean and standard deviation those of the drawn
    depths (the detector's own error is a small part of the 0.5 mm spread), every repeat has
    both, the pre-drops are not layers; one repeat whose first drop is too small to be a puncture
    on its own is found by the others."""
    curves = repeats(3, pre_drop_n=0.8)
    weak = layered_curve(np.random.default_rng(9), depths_m=(0.0138, 0.0202), drop_fractions=(0.12, 0.3),
                         pre_drop_m=None)
    shared = shared_punctures([since_contact(c) for c in curves + [weak]], [c.force_n for c in curves + [weak]])
    assert len(shared.layers) == 2
    for k, layer in enumerate(shared.layers):
        made = [c.puncture_depths_m[k] if k == 0 else rounded_peak_depth(c) for c in curves + [weak]]
        print(f'layer {k}: {layer.depth_m * 1e3:.2f} +- {layer.depth_sd_m * 1e3:.2f} mm (made '
              f'{np.mean(made) * 1e3:.2f} +- {np.std(made, ddof=1) * 1e3:.2f}), {layer.found}/{layer.repeats}, '
              f'{layer.assisted} assisted')
        assert layer.found == 6 and layer.depth_m == pytest.approx(np.mean(made), abs=2e-4)
        assert layer.depth_sd_m == pytest.approx(np.std(made, ddof=1), rel=0.35)
    assert shared.layers[0].assisted == 1 and shared.by_repeat[5][0].drop_n < 0.15 * shared.by_repeat[5][0].force_n
    assert sum(len(p) for p in shared.pre_drops) == 5
    assert [p.layer for p in shared.punctures_of(0)] == [0, 1]


def test_a_stray_drop_of_one_repeat_is_no_layer():
    curves = repeats(4, count=4, pre_drop_m=None)
    stray = curves[0]
    x = since_contact(stray)
    stray.force_n = stray.force_n - np.where((x > 0.017) & (x < 0.0178), 1.5, 0.0)   # a tear in one repeat
    shared = shared_punctures([since_contact(c) for c in curves], [c.force_n for c in curves])
    assert len(shared.layers) == 2


def test_punctures_pair_by_layer_where_both_know_it_and_by_distance_otherwise():
    from tissue_sim_ros.analysis.compare.force_events import Puncture
    measured = [Puncture(10, 0.010, 4.0, 2.0, layer=0), Puncture(30, 0.018, 5.0, 1.0, layer=1)]
    simulated = [Puncture(12, 0.0165, 4.1, 2.0, layer=1)]          # layer 0 gave way without a drop
    assert pair_punctures(measured, simulated) == [(measured[1], simulated[0])]
    unlabelled = [Puncture(12, 0.0165, 4.1, 2.0)]
    assert pair_punctures(measured, unlabelled) == [(measured[1], unlabelled[0])]    # the nearer
    assert pair_punctures(measured, unlabelled, max_distance_m=1e-3) == []


def test_a_simulated_puncture_within_the_repeats_spread_is_no_miss_of_the_samples_between():
    """compare's pointwise NRMSE: a simulated puncture 1 mm from the data's, where the repeats
    themselves spread over 2.5 mm, leaves the samples between the two out, so a curve that is the
    data's but for that scores 0; the same puncture 4 mm away (outside the spread) charges them."""
    from tissue_sim_ros.analysis.compare.compare import away_from_events
    from tissue_sim_ros.analysis.compare.shared_punctures import within_spread
    from tissue_sim_ros.analysis.compare.force_events import Puncture
    from tissue_sim_ros.analysis.compare.force_metrics import curve_errors
    from tissue_sim_ros.analysis.compare.shared_punctures import Layer
    x = np.linspace(0.0, 0.02, 2001)

    def curve(depth):
        return np.where(x <= depth, 300.0 * x, 1.0 + 50.0 * x)      # the same level after it
    measured = curve(0.010)
    layer = Layer(0.0105, 0.0009, (0.009, 0.0115), 3.1, 0.2, (2.9, 3.3), 2.0, 5, 5)
    scores = {}
    for offset in (0.001, 0.004):
        simulated = curve(0.010 + offset)
        m = Puncture(int(np.searchsorted(x, 0.010)), 0.010, 3.0, 2.0, layer=0)
        s = Puncture(int(np.searchsorted(x, 0.010 + offset)), 0.010 + offset, 3.0, 2.0, layer=0)
        between = [(m, s)] if within_spread(m, s, [layer]) else []
        kept = np.where(away_from_events(x, [m, s], between=between), simulated, np.nan)
        scores[offset] = curve_errors(measured, kept)['nrmse']
    print(scores)
    assert scores[0.001] == pytest.approx(0.0, abs=1e-12) and scores[0.004] > 0.25

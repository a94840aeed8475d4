"""benchmarks/bench_sfm.py: the far run's view set it bundle-adjusts."""


def test_view_set_spreads_views_over_the_recording_each_with_its_partner(benchmark_module):
    views = benchmark_module("bench_sfm").view_set(80)
    assert len(views) == 34 and views == sorted(set(views))
    assert views[0] == 0 and views[-1] == 79
    firsts = views[::2]
    assert all(v + 2 in views for v in firsts)
    assert max(b - a for a, b in zip(firsts, firsts[1:])) <= 5      # 17 views over 78 frames: every 4-5 frames

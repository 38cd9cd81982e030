"""map-features' retries: a model that the marker alignment refuses as bent is reconstructed
again with the other matching, then another seed; every attempt is reported, and when none
aligns the error names each residual, the likely cause and what to try. (The reconstruction
and alignment are replaced by stand-ins here: test_feature_mapping runs the real ones.)"""

from pathlib import Path

import pytest

from rs_localizer.mapping import colmap


@pytest.fixture
def fake(monkeypatch, tmp_path):
    calls = []
    outcomes = {}

    def reconstruct(images, camera, work, progress=None, matching="sequential", seed=0):
        calls.append((matching, seed))
        return Path(work) / f"model_{matching}_{seed}"

    def align(model, images, markers, max_residual=0.02):
        res = outcomes.get(model.name, 0.3)
        if res > max_residual:
            raise colmap.BentModelError(f"marker alignment residual {res * 100:.1f} cm RMS")
        return f"aligned {model.name}"

    monkeypatch.setattr(colmap, "reconstruct", reconstruct)
    monkeypatch.setattr(colmap, "align_to_markers", align)
    return calls, outcomes, tmp_path


def test_bent_model_is_reconstructed_with_the_other_matching(fake):
    calls, outcomes, tmp = fake
    outcomes["model_exhaustive_0"] = 0.009
    model, al, tried = colmap.reconstruct_aligned("photos", None, tmp, "m.yaml", progress=None)
    assert calls == [("sequential", 0), ("exhaustive", 0)]
    assert al == "aligned model_exhaustive_0" and model.name == "model_exhaustive_0"
    assert [(a.matching, a.seed) for a in tried] == calls
    assert "30.0 cm" in tried[0].error and tried[1].alignment == al


def test_first_model_that_aligns_is_kept(fake):
    calls, outcomes, tmp = fake
    outcomes["model_sequential_0"] = 0.005
    _, _, tried = colmap.reconstruct_aligned("photos", None, tmp, "m.yaml", progress=None)
    assert calls == [("sequential", 0)] and len(tried) == 1


def test_a_model_that_stays_bent_is_refused_with_the_cause(fake):
    calls, _, tmp = fake
    with pytest.raises(ValueError, match="bent reconstruction") as e:
        colmap.reconstruct_aligned("photos", None, tmp, "m.yaml", attempts=3, progress=None)
    assert calls == [("sequential", 0), ("exhaustive", 0), ("sequential", 1)]
    assert str(e.value).count("30.0 cm") == 3 and "after 3 attempt(s)" in str(e.value)
    with pytest.raises(ValueError, match="attempts must be >= 1"):
        colmap.reconstruct_aligned("photos", None, tmp, "m.yaml", attempts=0, progress=None)


def test_too_few_markers_is_not_retried(fake, monkeypatch):
    calls, _, tmp = fake

    def few(*a, **k):
        raise ValueError("marker alignment needs >= 3 markers")

    monkeypatch.setattr(colmap, "align_to_markers", few)
    with pytest.raises(ValueError, match="needs >= 3 markers"):
        colmap.reconstruct_aligned("photos", None, tmp, "m.yaml", progress=None)
    assert len(calls) == 1

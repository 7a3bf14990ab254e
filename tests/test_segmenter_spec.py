"""Segmenter specs parsed once (recon.segmentation.spec) and trackers built by name."""

from __future__ import annotations

from pathlib import Path

import pytest

from branch_gym.sensing import SimSegmenterSpec, check_segmenter_spec
from recon.replay import ReplaySegmenterSpec
from recon.segmentation.segmenter import default_weights_path, weights_path_of
from recon.segmentation.spec import SegmenterSpec, is_learned_segmenter
from recon.tracking import DepthOracleTracker, LucasKanadeTracker, make_tracker


@pytest.mark.parametrize(
    ("text", "kind", "option"),
    [("learned", "learned", None), ("learned:~/w/a:b.pt", "learned", "~/w/a:b.pt")],
)
def test_a_learned_spec_parses_and_prints_back_as_written(text, kind, option) -> None:
    spec = SegmenterSpec.parse(text)
    assert (spec.kind, spec.option) == (kind, option)
    assert str(spec) == text and spec.is_learned


@pytest.mark.parametrize(
    "text", ["gt", "noisy:mild", "noisy:moderate", "noisy:severe", "learned", "learned:x.pt"]
)
def test_the_simulators_specs_print_back_as_written(text) -> None:
    assert str(SimSegmenterSpec.parse(text)) == text
    assert SimSegmenterSpec.parse(text).is_learned == text.startswith("learned")


@pytest.mark.parametrize(
    ("cls", "text", "message"),
    [
        (SegmenterSpec, "gt", r"unknown segmenter 'gt'; valid: \('learned', 'learned:PATH'\)"),
        (SegmenterSpec, "learned:", "bad segmenter 'learned:'"),
        (SimSegmenterSpec, "noisy:awful", "bad segmenter 'noisy:awful'.*noisy:mild"),
        (SimSegmenterSpec, "noisy", "segmenter 'noisy' needs one of"),
        (SimSegmenterSpec, "gt:exact", "bad segmenter 'gt:exact'"),
        (SimSegmenterSpec, "mask", "unknown segmenter 'mask'"),
        (ReplaySegmenterSpec, "gt", r"unknown segmenter 'gt'; valid: \('mask', 'learned'"),
        (ReplaySegmenterSpec, None, "a segmenter spec is text"),
    ],
)
def test_a_bad_spec_is_named_with_the_valid_ones(cls, text, message) -> None:
    with pytest.raises(ValueError, match=message):
        cls.parse(text)


def test_learned_is_recognised_whatever_package_the_other_kinds_belong_to() -> None:
    assert is_learned_segmenter("learned:x.pt") and is_learned_segmenter("learned")
    for other in ("gt", "noisy:mild", "mask", None, 3, "learnedx"):
        assert not is_learned_segmenter(other)
    assert is_learned_segmenter(SimSegmenterSpec.parse("learned"))


def test_the_weights_of_a_spec(tmp_path: Path) -> None:
    assert weights_path_of("learned") == default_weights_path()
    assert weights_path_of(SimSegmenterSpec.parse("learned:~/w.pt")) == Path("~/w.pt").expanduser()
    with pytest.raises(ValueError, match="unknown segmenter 'gt'"):
        weights_path_of("gt")
    check_segmenter_spec("learned")  # the shipped weights exist
    with pytest.raises(ValueError, match=r"weights file .*missing\.pt does not exist"):
        check_segmenter_spec(f"learned:{tmp_path / 'missing.pt'}")


def test_trackers_by_name() -> None:
    assert isinstance(make_tracker("lk"), LucasKanadeTracker)
    assert isinstance(make_tracker("oracle"), DepthOracleTracker)
    with pytest.raises(ValueError, match=r"unknown tracker 'oracle': expected one of \('lk',\)"):
        make_tracker("oracle", ("lk",))
    with pytest.raises(ValueError, match="unknown tracker 'pips'"):
        make_tracker("pips")

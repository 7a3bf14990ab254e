"""Segmenter specs: the text ``KIND`` or ``KIND:OPTION`` that names what makes a scan's masks.

One parser (:meth:`SegmenterSpec.parse`) for every command, config and recording. recon's own
kind is the one that runs on real frames:

=====================  ==================================================================
spec                   masks from
=====================  ==================================================================
``learned``            the shipped network (:func:`recon.segmentation.load_segmenter`)
``learned:PATH``       the network of another weights file
=====================  ==================================================================

A package that makes masks another way adds its kinds in a subclass (``KINDS``): the replay's
``mask`` (the recording's masks, :class:`recon.replay.ReplaySegmenterSpec`), the simulator's
``gt`` and ``noisy:PRESET`` (the renderer's labels, ``branch_gym.sensing.SimSegmenterSpec``).
Only the torch-free standard library is imported here: configs parse specs without the network.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import ClassVar

LEARNED_KIND = "learned"
"""The kind of a learned segmenter's spec: ``learned`` or ``learned:PATH``."""
WEIGHTS_DIR = Path(__file__).resolve().parent / "weights"
"""The shipped weights files: package data beside this module."""
SHIPPED_WEIGHTS = WEIGHTS_DIR / "orchard_flow.pt"
"""The weights ``learned`` names."""


@dataclass(frozen=True)
class SpecKind:
    """What follows the colon of one kind of spec.

    Attributes:
        choices: The options it takes: a tuple of words (one of them is required), or None for
            any text, optional (a weights path); ``()``: no option.
        option_name: How the help and error texts call a free option (``PATH``).
    """

    choices: tuple[str, ...] | None = ()
    option_name: str = "OPTION"

    def forms(self, kind: str) -> list[str]:
        """The spellings of this kind, for messages: ``["learned", "learned:PATH"]``."""
        if self.choices is None:
            return [kind, f"{kind}:{self.option_name}"]
        if not self.choices:
            return [kind]
        return [f"{kind}:{choice}" for choice in self.choices]


@dataclass(frozen=True)
class SegmenterSpec:
    """A parsed segmenter spec (module docstring); ``str(spec)`` gives its text back.

    Attributes:
        kind: What makes the masks (a key of :attr:`KINDS`).
        option: The text after the colon (a weights path, a preset), or None.
    """

    kind: str
    option: str | None = None

    KINDS: ClassVar[Mapping[str, SpecKind]] = {LEARNED_KIND: SpecKind(None, "PATH")}
    """The kinds this class parses (subclasses add theirs)."""

    @classmethod
    def parse(cls, text: str | SegmenterSpec) -> SegmenterSpec:
        """The spec of ``text`` (a parsed spec is parsed again from its text, with these kinds).

        Raises:
            ValueError: An unknown kind or a bad option, naming the spec and the valid ones.
        """
        if isinstance(text, SegmenterSpec):
            text = str(text)
        if not isinstance(text, str):
            raise ValueError(f"a segmenter spec is text, got {text!r}; valid: {cls.valid()}")
        kind, colon, option = text.partition(":")
        rule = cls.KINDS.get(kind)
        if rule is None:
            raise ValueError(f"unknown segmenter {text!r}; valid: {cls.valid()}")
        if not colon:
            if rule.choices:
                raise ValueError(f"segmenter {text!r} needs one of {rule.forms(kind)}")
            return cls(kind)
        if rule.choices is None and option:
            return cls(kind, option)
        if rule.choices and option in rule.choices:
            return cls(kind, option)
        raise ValueError(f"bad segmenter {text!r}: expected one of {rule.forms(kind)}")

    @classmethod
    def valid(cls) -> tuple[str, ...]:
        """Every spelling this class parses, for messages and help texts."""
        return tuple(form for kind, rule in cls.KINDS.items() for form in rule.forms(kind))

    @property
    def is_learned(self) -> bool:
        """The masks come from a network (approximate masks: ``ModelerConfig.for_masks``)."""
        return self.kind == LEARNED_KIND

    def __str__(self) -> str:
        return self.kind if self.option is None else f"{self.kind}:{self.option}"


def is_learned_segmenter(text: object) -> bool:
    """Whether a spec of any package's kinds (text, or parsed) names a learned segmenter.

    For specs read back from a recording or a config, whose other kinds may belong to another
    package (``gt``, ``mask``): any value that is not a learned spec is no.
    """
    if isinstance(text, SegmenterSpec):
        return text.is_learned
    try:
        return SegmenterSpec.parse(text).is_learned
    except ValueError:
        return False


def default_weights_path() -> Path:
    """The shipped weights (:data:`SHIPPED_WEIGHTS`)."""
    return SHIPPED_WEIGHTS


def weights_path_of(spec: str | SegmenterSpec) -> Path:
    """The weights file a learned segmenter spec names.

    Args:
        spec: ``"learned"`` (:func:`default_weights_path`) or ``"learned:PATH"``, text or parsed.

    Raises:
        ValueError: Not a learned segmenter spec.
    """
    option = SegmenterSpec.parse(spec).option  # this class parses learned specs only
    return default_weights_path() if option is None else Path(option).expanduser()

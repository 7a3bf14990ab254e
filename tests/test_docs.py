"""The docs' promises: the README stays a map, results pages say how to regenerate them."""

from __future__ import annotations

import re
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
RESULTS = sorted((ROOT / "docs" / "results").glob("*.md"))
README_MAX_LINES = 150  # a map a newcomer reads in minutes (issue 33)


def test_the_readme_is_a_map_whose_links_exist() -> None:
    readme = (ROOT / "README.md").read_text()
    assert len(readme.splitlines()) <= README_MAX_LINES
    for target in re.findall(r"\]\(([^)#]+)\)", readme):
        assert (ROOT / target).exists(), target


@pytest.mark.parametrize("page", [p for p in RESULTS if p.name != "history.md"], ids=str)
def test_a_results_page_opens_with_its_command_and_date(page: Path) -> None:
    text = page.read_text()
    head = text.split("\n\n", 3)
    assert head[0].startswith("# ") and head[1].startswith("```bash"), page.name
    assert re.search(r"Measured \d{4}-\d{2}-\d{2}", head[2]), page.name


def test_every_shipped_recipe_and_model_card_is_listed() -> None:
    recipes = (ROOT / "configs" / "README.md").read_text()
    for config in (ROOT / "configs").glob("*.json"):
        assert config.name in recipes, config.name

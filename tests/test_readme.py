"""The README's Python snippets run as written."""

import re
from pathlib import Path

import pytest

README = Path(__file__).resolve().parents[1] / "README.md"
SNIPPETS = re.findall(r"```python\n(.*?)```", README.read_text(), flags=re.S)


@pytest.mark.parametrize("index", range(len(SNIPPETS)))
def test_readme_snippet_runs(index, tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    exec(compile(SNIPPETS[index], f"README.md snippet {index}", "exec"), {"__name__": "__main__"})


def test_readme_names_the_ci_command():
    ci = (README.parent / ".ci" / "run").read_text()
    command = 'python3 -m venv .venv && . .venv/bin/activate && pip install -e ".[test]" && pytest'
    assert command in README.read_text() and command in ci


def test_readme_is_short_with_pictures_and_closed_fences():
    text = README.read_text()
    assert len(text.splitlines()) <= 150
    images = re.findall(r"!\[[^\]]*\]\(([^)]+)\)", text)
    assert len(images) >= 2 and all((README.parent / p).is_file() for p in images), images
    fences = [line for line in text.splitlines() if line.startswith("```")]
    assert len(fences) % 2 == 0 and all(f == "```" for f in fences[1::2]), fences  # every fence closes


def test_docs_index_links_every_page_and_links_resolve():
    docs = README.parent / "docs"
    index = (docs / "README.md").read_text()
    pages = {p.name for p in docs.glob("*.md")} - {"README.md"}
    linked = set(re.findall(r"\]\(([^)#]+\.md)", index))
    assert pages <= linked, sorted(pages - linked)
    for page in (README, docs / "README.md", docs / "guide.md"):
        for target in re.findall(r"\]\(([^)#:]+)\)", page.read_text()):
            assert (page.parent / target).exists(), (page.name, target)

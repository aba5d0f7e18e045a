"""The project's texts: what a reader outside the tracker can follow."""
import re
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent

# The docs, the package, the benchmarks and the tests: a reader cannot look an issue up.
TEXTS = sorted(p for folder in ("docs", "pssd_fast", "benchmarks", "tests")
               for p in (ROOT / folder).rglob("*")
               if p.suffix in (".md", ".py", ".toml", ".txt"))
TEXTS += [ROOT / "README.md", ROOT / "pyproject.toml"]
ISSUE = re.compile(r"\b[Ii]ssues? #?\d+")


def test_no_text_cites_an_issue_number():
    cited = [f"{path.relative_to(ROOT)}:{n}"
             for path in TEXTS if path.is_file()
             for n, line in enumerate(path.read_text(errors="replace").splitlines(), 1)
             if ISSUE.search(line)]
    assert len(TEXTS) > 50 and not cited, cited

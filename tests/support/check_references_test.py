"""Tests of check_references.py on small folders made here: each rule must catch its case,
and a folder that keeps every rule must pass. (The repository itself is checked by the ctest
entry `repository_references`.)"""

import os
import sys

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))

import check_references  # noqa: E402

# Assembled, so that this file does not itself trip rule 1 in the repository.
DESIGN_NOTES = "DESIGN" + ".md"
SHARED_FOLDER = ".." + "/shared"
MISSING_PAGE = "docs/" + "metric.md"  # a page that does not exist


def make_tree(tmp_path, files):
    for rel, text in files.items():
        path = tmp_path / rel
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_text(text)
    return str(tmp_path)


CLEAN = {
    "README.md": "See [the docs](docs/README.md) and [units](docs/conventions.md#units).\n",
    "docs/README.md": "# Index\n\n[conventions](conventions.md), [top](../README.md), "
                      "[web](https://example.org/x.md)\n",
    "docs/conventions.md": "# Conventions\n\n## Units\n\n## Sampling: integrated and "
                           "pixel_centre\n\nBack to [units](#units).\n",
    "src/a.cc": "// The model: docs/conventions.md, Sampling.\n",
}


def test_a_clean_tree_passes(tmp_path):
    assert check_references.check(make_tree(tmp_path, CLEAN)) == []


def test_the_design_notes_and_the_shared_folder_are_caught(tmp_path):
    files = dict(CLEAN)
    files["src/b.cc"] = f"// see {DESIGN_NOTES} pitfall 1\n"
    files["tests/c.cc"] = f'std::string paper = "{SHARED_FOLDER}/paper/x.tex";\n'
    # The real bench frames there may be named: the tests that read them skip without them.
    files["tests/d.cc"] = f'std::string root = "{SHARED_FOLDER}/realdata";\n'
    problems = check_references.check(make_tree(tmp_path, files))
    assert len(problems) == 2
    assert problems[0].startswith("src/b.cc:1:")
    assert problems[1].startswith("tests/c.cc:1:")


def test_a_link_to_a_missing_file_is_caught(tmp_path):
    files = dict(CLEAN)
    files["testdata/README.md"] = "Made as [described](../docs/missing.md).\n"
    problems = check_references.check(make_tree(tmp_path, files))
    assert problems == ["testdata/README.md:1: link '../docs/missing.md' points to a "
                        "missing file"]


def test_a_link_to_a_missing_section_is_caught(tmp_path):
    files = dict(CLEAN)
    files["README.md"] = "[units](docs/conventions.md#noise)\n[here](#nowhere)\n"
    problems = check_references.check(make_tree(tmp_path, files))
    assert len(problems) == 2
    assert "docs/conventions.md#noise" in problems[0]
    assert "#nowhere" in problems[1]


def test_a_mention_of_a_missing_docs_page_is_caught(tmp_path):
    files = dict(CLEAN)
    files["src/d.cc"] = f"// see {MISSING_PAGE}\n"
    problems = check_references.check(make_tree(tmp_path, files))
    assert problems == [f"src/d.cc:1: names '{MISSING_PAGE}', which does not exist"]


def test_a_mention_of_a_missing_test_file_is_caught(tmp_path):
    present, moved = "tests/" + "unit/a_test.cc", "tests/" + "a_test.cc"  # assembled: rule 4
    files = dict(CLEAN)
    files[present] = "// a test\n"
    files["src/e.cc"] = f"// checked in {present} and {moved}\n"
    problems = check_references.check(make_tree(tmp_path, files))
    assert problems == [f"src/e.cc:1: names '{moved}', which does not exist"]


def test_code_examples_are_not_links(tmp_path):
    files = dict(CLEAN)
    files["docs/README.md"] = ("# Index\n\n    x = a[0](missing.md)\n\n```\n"
                               "[not a link](missing.md)\n```\n")
    assert check_references.check(make_tree(tmp_path, files)) == []


def test_anchors_follow_githubs_rule():
    # GitHub: lower case, punctuation other than '-' and '_' dropped, spaces become '-'.
    assert check_references.github_anchor("Sampling: integrated and pixel_centre") == \
        "sampling-integrated-and-pixel_centre"
    assert check_references.github_anchor("fit: chain.fits") == "fit-chainfits"
    assert check_references.github_anchor("Verdicts: ok, suspect, invalid") == \
        "verdicts-ok-suspect-invalid"


def test_main_exits_nonzero_on_a_problem(tmp_path, capsys):
    files = dict(CLEAN)
    files["src/b.cc"] = f"// {DESIGN_NOTES}\n"
    root = make_tree(tmp_path, files)
    assert check_references.main(["check_references.py", root]) == 1
    assert "src/b.cc:1:" in capsys.readouterr().out

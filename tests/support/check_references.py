#!/usr/bin/env python3
"""Checks that the repository refers only to files it holds.

Usage: check_references.py [REPOSITORY_ROOT]   (default: the current folder)

Four rules, over the files git tracks (every file below the root, .git and build folders
aside, when the root is not a git checkout):

1. No file names the design notes, the style notes or the shared folder outside the
   repository, except the real bench frames there, which the tests use when they are present
   and skip otherwise (the names are assembled below, so this script does not match itself).
2. Every relative link of a Markdown file, [text](target), points to a file or folder that
   exists; when the target is a Markdown file with a #fragment, that file has a heading
   whose GitHub anchor is the fragment. Links to web pages are not checked.
3. Every mention of a documentation page by its path from the root, docs/<name>.md, in
   any file names a page that exists (source comments and report texts point readers
   there; a longer relative path such as ../docs/<name>.md is a link, rule 2).
4. Every mention of a test file by its path from the root, tests/<folder>/<name>_test.cc (or
   .py), names a file that exists: the tests live in tiers (tests/README.md), and a comment
   pointing to where a case was before it moved sends a reader nowhere.

Prints one line per problem (file:line: what) and exits 1 if there is any, else 0.
Standard library only.
"""

import os
import re
import subprocess
import sys

FORBIDDEN = ("DESIGN" + ".md", "STYLE" + ".md", ".." + "/shared")
ALLOWED = (".." + "/shared/realdata",)
SKIPPED_FOLDERS = {".git", "build"}
MARKDOWN_LINK = re.compile(r"\[[^\]]*\]\(([^)\s]+)\)")
DOCS_MENTION = re.compile(r"(?<![\w./-])docs/[A-Za-z0-9_-]+\.md")
TEST_MENTION = re.compile(r"(?<![\w./-])tests/[A-Za-z0-9_/-]*_test\.(?:cc|py)")


def tracked_files(root):
    """Paths relative to root: git's tracked files, or a walk when git cannot list them."""
    try:
        out = subprocess.run(["git", "-C", root, "ls-files", "-z"], check=True,
                             capture_output=True).stdout
        files = [f for f in out.decode("utf-8", "surrogateescape").split("\0") if f]
        if files:
            return sorted(f for f in files if os.path.isfile(os.path.join(root, f)))
    except (OSError, subprocess.CalledProcessError):
        pass
    files = []
    for folder, subfolders, names in os.walk(root):
        subfolders[:] = [d for d in subfolders
                         if d not in SKIPPED_FOLDERS and not d.startswith("build")]
        for name in names:
            files.append(os.path.relpath(os.path.join(folder, name), root))
    return sorted(files)


def read_text(path):
    """The file as text, or None for binary data (a NUL byte in it)."""
    with open(path, "rb") as f:
        data = f.read()
    if b"\0" in data:
        return None
    return data.decode("utf-8", "replace")


def github_anchor(heading):
    """The fragment GitHub gives a heading: lower case, punctuation dropped, spaces to '-'."""
    text = re.sub(r"[`*]", "", heading.strip().lower())
    text = re.sub(r"[^\w\- ]", "", text)
    return text.replace(" ", "-")


def anchors_of(markdown_text):
    anchors = set()
    in_code = False
    for line in markdown_text.splitlines():
        if line.lstrip().startswith("```"):
            in_code = not in_code
        match = re.match(r"#{1,6}\s+(.*)", line)
        if match and not in_code:
            anchors.add(github_anchor(match.group(1)))
    return anchors


def check(root):
    problems = []
    files = tracked_files(root)
    for rel in files:
        text = read_text(os.path.join(root, rel))
        if text is None:
            continue
        lines = text.splitlines()
        for number, line in enumerate(lines, start=1):
            allowed_free = line
            for name in ALLOWED:
                allowed_free = allowed_free.replace(name, "")
            for name in FORBIDDEN:
                if name in allowed_free:
                    problems.append(f"{rel}:{number}: refers to '{name}', which is not in the "
                                    "repository")
            for mention in DOCS_MENTION.findall(line) + TEST_MENTION.findall(line):
                if not os.path.isfile(os.path.join(root, mention)):
                    problems.append(f"{rel}:{number}: names '{mention}', which does not exist")
        if not rel.endswith(".md"):
            continue
        in_code = False
        for number, line in enumerate(lines, start=1):
            # Indented blocks and fenced code are examples, not links.
            if line.lstrip().startswith("```"):
                in_code = not in_code
            if in_code or line.startswith("    "):
                continue
            for target in MARKDOWN_LINK.findall(line):
                if re.match(r"[a-z][a-z0-9+.-]*:", target) or target.startswith("#"):
                    continue  # a web address, mailto:, or a fragment of this page
                path, _, fragment = target.partition("#")
                resolved = os.path.normpath(os.path.join(root, os.path.dirname(rel), path))
                if not os.path.exists(resolved):
                    problems.append(f"{rel}:{number}: link '{target}' points to a missing file")
                elif fragment and resolved.endswith(".md") and os.path.isfile(resolved):
                    if fragment not in anchors_of(read_text(resolved) or ""):
                        problems.append(f"{rel}:{number}: link '{target}': no such section")
        # Fragments of the page itself.
        own = anchors_of(text)
        for number, line in enumerate(lines, start=1):
            if line.startswith("    "):
                continue
            for target in MARKDOWN_LINK.findall(line):
                if target.startswith("#") and target[1:] not in own:
                    problems.append(f"{rel}:{number}: link '{target}': no such section")
    return problems


def main(argv):
    root = argv[1] if len(argv) > 1 else "."
    if not os.path.isdir(root):
        print(f"check_references: '{root}' is not a folder", file=sys.stderr)
        return 2
    problems = check(root)
    for p in problems:
        print(p)
    if problems:
        print(f"check_references: {len(problems)} problem(s)", file=sys.stderr)
        return 1
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv))

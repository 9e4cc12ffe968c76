"""Checks that the repository's Markdown files name things that exist.

    /usr/bin/python3 tests/docs/check_doc_refs.py SOURCE_DIR NIMBUS NIMBUSD

Every *.md file under SOURCE_DIR is read, except in build trees (a folder
holding CMakeCache.txt, or a root build*/ folder), node_modules/ (npm's
packages) and tests/faults/ (patches quote old text). The expected values
come from the tree on disk and from the programs' own --help:

1. Links: a relative link or image, [x](path#anchor) or <a href=...>,
   names an existing file or folder; an #anchor into a Markdown file names
   one of its headings, slugged as GitHub does (lower case, punctuation
   other than '-' and '_' dropped, spaces to '-', repeats suffixed -1, -2).
2. Paths: every token in code (`spans`, fenced and indented blocks) that
   starts with a top-level folder (core/, docs/, ...) or is a root file
   exists; so does one starting with a folder beside the Markdown file
   (deploy/README.md's systemd/...), a bare NAME.md beside it or at the
   root, and a bare source file name (NAME.h, .cc, .py, .sh, .proto, .mjs,
   .cmake, .patch; the text says which folder) somewhere in the tree.
   A path never holds ':', so ':12', ':12:3' or '::Symbol' after it is
   dropped, as is '#anchor'. Globs (*, ?, [..], {a,b}) must match, every
   alternative of {a,b}, and a placeholder (<name>, ...) stands for any
   text. What is not in the tree is not checked: paths under build/ and
   out/ (outputs; neither is a top-level source folder), and a path after
   '>' or '>>' (the file a command writes).
3. Options: in code, a command line whose program is nimbusd or nimbus
   (any folder) uses only long options that program's --help lists: for
   nimbus, the options before the subcommand are the global ones and those
   after it the subcommand's ('nimbus SUB --help'), and the subcommand
   itself exists (a global option after it is refused by nimbus too). A
   placeholder subcommand (<cmd>, CMD, ...) allows any subcommand's options.
4. Every examples/*.json named in prose (outside code) exists too. (That
   every example validates is SpecConvert.EveryExampleValidates.)

Each problem is printed as FILE:LINE: message; the exit status is 1 if any.
"""
import fnmatch
import glob
import os
import re
import subprocess
import sys
import urllib.parse

TOP_DIRS = {"bench", "client", "core", "dcc", "deploy", "docs", "examples",
            "proto", "python", "scripts", "server", "tests"}
ROOT_FILES = {"README.md", "CMakeLists.txt", "CMakePresets.json", ".gitignore",
              ".clang-format", ".containerignore"}
FENCE = re.compile(r"^\s*(`{3,}|~{3,})")
LIST_ITEM = re.compile(r"^(\s*)(?:[-*+]|\d+[.)])\s+")
CODE_SPAN = re.compile(r"(?<!`)(`+)(?!`)(.+?)(?<!`)\1(?!`)", re.S)
LINK = re.compile(r"!?\[(?:[^\[\]]|\[[^\]]*\])*\]\(\s*(<[^>]*>|[^)\s]+)(?:\s+\"[^\"]*\")?\s*\)")
REF_DEF = re.compile(r"^ {0,3}\[[^\]]+\]:\s*(\S+)")
HTML_REF = re.compile(r"<(?:a|img)\b[^>]*?\b(?:href|src)=\"([^\"]+)\"", re.I)
HTML_ANCHOR = re.compile(r"<a\b[^>]*?\b(?:name|id)=\"([^\"]+)\"", re.I)
ATX = re.compile(r"^ {0,3}(#{1,6})(?:\s+(.*?))?(?:\s+#+)?\s*$")
EXAMPLE_JSON = re.compile(r"(?<![\w./-])examples/[\w./-]*\.json")
SPLIT = re.compile(r"(?:[^\s`\"'(),;|={}]|\{[^{}\s]*\})+")
SOURCE_NAME = re.compile(r"[\w.*<>+-]+\.(h|hpp|cc|cpp|py|sh|proto|mjs|cmake|patch)")
PLACEHOLDER = re.compile(r"<[^<>/]*>|…|(?<=/)\.\.\.(?=/|$)")


class Doc:
    """One Markdown file split into prose lines and code pieces."""

    def __init__(self, root, rel):
        self.rel = rel
        self.dir = os.path.dirname(os.path.join(root, rel))
        with open(os.path.join(root, rel), encoding="utf-8") as f:
            self.lines = f.read().split("\n")
        self.prose = []     # (line number, text), code spans blanked out
        self.code = []      # (line number, text) of spans and block lines
        self.headings = []  # (line number, heading text)
        self._continued = None  # a code line ending in '\\', awaiting the next
        self._split()

    def _code_line(self, n, line):
        """Lines joined by a trailing backslash are one, at the first's number."""
        if self._continued:
            n, line = self._continued[0], self._continued[1] + " " + line
        self._continued = (n, line[:-1]) if line.endswith("\\") else None
        if not self._continued:
            self.code.append((n, line))

    def _split(self):
        """Fenced blocks; indented blocks (4 columns past the enclosing list
        item's text); paragraphs of prose between them."""
        fence, indented, para, items = None, False, [], []
        for n, line in enumerate(self.lines, 1):
            if fence:
                if re.match(r"^\s*" + fence[0] + "{" + str(len(fence)) + r",}\s*$", line):
                    fence = None
                else:
                    self._code_line(n, line)
                continue
            depth = len(line) - len(line.lstrip())
            code = (line.strip() and depth >= (items[-1] if items else 0) + 4
                    and (indented or not para))
            item = None if code else LIST_ITEM.match(line)
            if item:
                while items and items[-1] > len(item.group(1)):
                    items.pop()
                items.append(len(item.group(0)))
            if not item and not code and line.strip() and not para:
                while items and depth < items[-1]:
                    items.pop()
            fenced = FENCE.match(line) if not code else None
            if fenced or code or not line.strip():
                self._paragraph(para)
                para = []
            indented = bool(code) or (indented and not line.strip())
            if fenced:
                fence = fenced.group(1)
            elif code:
                self._code_line(n, line)
            elif line.strip():
                para.append((n, line))
        self._paragraph(para)

    def _paragraph(self, para):
        """Code spans may run across the lines of one paragraph."""
        if not para:
            return
        text = "\n".join(line for _, line in para)
        blanked = list(text)
        for m in CODE_SPAN.finditer(text):
            line = para[text.count("\n", 0, m.start())][0]
            self.code.append((line, m.group(2).replace("\n", " ")))
            blanked[m.start():m.end()] = " " * (m.end() - m.start())
        prose = "".join(blanked).split("\n")
        for (n, line), plain in zip(para, prose):
            self.prose.append((n, plain))
            h = ATX.match(line)
            if h:
                self.headings.append((n, h.group(2) or ""))
        self._setext(para)

    def _setext(self, para):
        if len(para) >= 2 and re.match(r"^ {0,3}(=+|-+)\s*$", para[-1][1]):
            self.headings.append((para[0][0], " ".join(l for _, l in para[:-1])))


def slug(heading):
    """GitHub's anchor for a heading's text."""
    text = CODE_SPAN.sub(lambda m: m.group(2), heading)
    text = re.sub(r"!?\[([^\]]*)\]\([^)]*\)", r"\1", text)
    text = re.sub(r"<[^>]+>", "", text)
    text = re.sub(r"(?<!\w)[*_]+(?=\S)|(?<=\S)[*_]+(?!\w)", "", text)
    text = re.sub(r"[^\w\- ]", "", text.strip().lower())
    return text.replace(" ", "-")


def anchors(doc):
    seen, out = {}, set()
    for _, heading in doc.headings:
        base = slug(heading)
        count = seen.get(base, 0)
        seen[base] = count + 1
        out.add(base if count == 0 else f"{base}-{count}")
    for line in doc.lines:
        out.update(HTML_ANCHOR.findall(line))
    return out


class Checker:
    def __init__(self, root, nimbus, nimbusd):
        self.root = root
        self.problems = []
        self.counts = {"files": 0, "links": 0, "anchors": 0, "paths": 0, "options": 0}
        self.docs = {}
        self.nimbusd = help_options([nimbusd])
        self.nimbus = help_options([nimbus])
        self.subcommands = {s: help_options([nimbus, s]) for s in subcommands(nimbus)}
        self.top = TOP_DIRS | {d for d in os.listdir(root) if is_source_dir(root, d)}
        self.file_names = {os.path.basename(f) for f in tree_files(root, False)}

    def report(self, doc, line, message):
        self.problems.append(f"{doc.rel}:{line}: {message}")

    def doc(self, rel):
        if rel not in self.docs:
            self.docs[rel] = Doc(self.root, rel)
        return self.docs[rel]

    def run(self):
        for rel in markdown_files(self.root):
            self.counts["files"] += 1
            doc = self.doc(rel)
            self.check_links(doc)
            for n, code in doc.code:
                self.check_paths(doc, n, code)
                self.check_commands(doc, n, code)
            for n, line in doc.prose:  # code is checked as paths above
                for m in EXAMPLE_JSON.finditer(line):
                    if not os.path.isfile(os.path.join(self.root, m.group(0))):
                        self.report(doc, n, f"no example {m.group(0)}")
        return self.problems

    # 1. Links
    def check_links(self, doc):
        for n, line in doc.prose:
            targets = [m.group(1).strip("<>") for m in LINK.finditer(line)]
            targets += REF_DEF.findall(line) + HTML_REF.findall(line)
            for target in targets:
                self.check_link(doc, n, target)

    def check_link(self, doc, n, target):
        if re.match(r"^[a-z][a-z0-9+.-]*:", target, re.I) or target.startswith("//"):
            return
        path, _, anchor = urllib.parse.unquote(target).partition("#")
        self.counts["links"] += 1
        full = os.path.normpath(os.path.join(doc.dir, path or os.path.basename(doc.rel)))
        if os.path.relpath(full, self.root).split(os.sep)[0] == "..":
            self.report(doc, n, f"link {target} leaves the repository")
            return
        if not os.path.exists(full):
            self.report(doc, n, f"link to a missing file: {target}")
            return
        if anchor and full.endswith(".md"):
            self.counts["anchors"] += 1
            target_doc = self.doc(os.path.relpath(full, self.root))
            if anchor not in anchors(target_doc):
                self.report(doc, n, f"link {target}: no heading #{anchor} in {target_doc.rel}")

    # 2. Paths
    def check_paths(self, doc, n, code):
        for m in SPLIT.finditer(code):
            token = re.sub(r"^\./", "", m.group(0)).split(":")[0].split("#")[0]
            token = token.rstrip(".,!?")
            if SOURCE_NAME.fullmatch(token):
                self.check_source_name(doc, n, token)
                continue
            places = self.places(doc, token)
            if not places or code[:m.start()].rstrip().endswith(">"):
                continue
            self.counts["paths"] += 1
            alternatives = braces(PLACEHOLDER.sub("*", token))
            missing = [a for a in alternatives if not any(path_exists(p, a) for p in places)]
            if missing:
                which = f" ({', '.join(missing)})" if len(alternatives) > 1 else ""
                self.report(doc, n, f"no such file or folder: {token}{which}")

    def check_source_name(self, doc, n, token):
        """A bare source file name (`vdb_fixtures.h` in a table of tests/support/)."""
        self.counts["paths"] += 1
        if not fnmatch.filter(self.file_names, PLACEHOLDER.sub("*", token)):
            self.report(doc, n, f"no file named {token} anywhere in the tree")

    def places(self, doc, token):
        """The folders a token is looked up in; none if it names no repository path."""
        first = token.split("/")[0]
        if "/" in token:
            if first in self.top:
                return [self.root]
            beside = os.path.join(doc.dir, first)  # deploy/README.md's `systemd/...`
            if first not in ("", ".", "..") and doc.dir != self.root and os.path.isdir(beside):
                return [doc.dir]
            return []
        if token in ROOT_FILES:
            return [self.root]
        return [doc.dir, self.root] if re.fullmatch(r"[\w.-]+\.md", token) else []

    # 3. Options
    def check_commands(self, doc, n, code):
        code = re.sub(r"(^|\s)#.*$", "", code)
        for command in re.split(r"\|\||&&|[|;(){}`]|\$\(", code):
            words = [w.strip("[]") for w in command.split()]
            while words and (words[0] in ("$", "exec", "time", "nohup", "env", "do", "then", "else")
                             or re.fullmatch(r"[A-Z_][A-Z0-9_]*=\S*", words[0])):
                words.pop(0)
            if not words:
                continue
            program = os.path.basename(words[0])
            if program == "nimbusd":
                self.check_options(doc, n, words[1:], self.nimbusd, "nimbusd")
            elif program == "nimbus":
                self.check_nimbus(doc, n, words[1:])

    def check_nimbus(self, doc, n, words):
        i = 0
        while i < len(words) and words[i].startswith("-"):
            name = words[i].split("=")[0]
            i += 2 if "=" not in words[i] and self.nimbus.get(name) else 1
        self.check_options(doc, n, words[:i], self.nimbus, "nimbus")
        if i == len(words):
            return
        if is_placeholder(words[i]):
            union = {}
            for options in self.subcommands.values():
                union.update(options)
            self.check_options(doc, n, words[i + 1:], union, "any nimbus subcommand")
            return
        if not re.fullmatch(r"[a-z][a-z0-9-]*(/[a-z][a-z0-9-]*)*", words[i]):
            return  # prose that happens to start with the word nimbus
        for sub in words[i].split("/"):  # "submit/render": either
            if sub not in self.subcommands:
                self.report(doc, n, f"nimbus has no subcommand {sub!r}")
                continue
            self.check_options(doc, n, words[i + 1:], self.subcommands[sub], f"nimbus {sub}",
                               self.nimbus)

    def check_options(self, doc, n, words, known, program, parent=None):
        for word in words:
            if not re.match(r"^--[A-Za-z]", word):
                continue
            name = word.split("=")[0].rstrip(".,")
            self.counts["options"] += 1
            if name in known:
                continue
            if parent and name in parent:
                self.report(doc, n, f"{name} is an option of nimbus itself: write it before "
                                    f"the subcommand ({program} does not take it)")
            else:
                self.report(doc, n, f"{program} has no option {name} (see its --help)")


def tree_files(root, skip_faults):
    """Paths of the source tree's files, relative to root, sorted."""
    for folder, dirs, files in os.walk(root):
        rel = os.path.relpath(folder, root)
        dirs[:] = sorted(d for d in dirs if not skipped_dir(root, rel, d, skip_faults))
        for f in sorted(files):
            yield os.path.normpath(os.path.join(rel, f))


def markdown_files(root):
    return [f for f in tree_files(root, True) if f.endswith(".md")]


def skipped_dir(root, rel, d, skip_faults=True):
    path = os.path.normpath(os.path.join(rel, d))
    return (d.startswith(".") or d == "node_modules"
            or (skip_faults and path == os.path.join("tests", "faults"))
            or (rel == "." and d.startswith("build"))
            or os.path.exists(os.path.join(root, path, "CMakeCache.txt")))


def is_source_dir(root, d):
    return (os.path.isdir(os.path.join(root, d)) and not skipped_dir(root, ".", d)
            and d != "out")


def is_placeholder(word):
    return bool(re.fullmatch(r"<[^>]*>|[A-Z][A-Z_]*|\.\.\.|…|\S*[*{].*", word))


def path_exists(base, path):
    if re.search(r"[*?\[]", path):
        return bool(glob.glob(os.path.join(base, path), recursive=True))
    return os.path.exists(os.path.join(base, path))


def braces(pattern):
    m = re.search(r"\{([^{}]*,[^{}]*)\}", pattern)
    if not m:
        return [pattern]
    out = []
    for alt in m.group(1).split(","):
        out += braces(pattern[:m.start()] + alt + pattern[m.end():])
    return out


def run_help(argv):
    done = subprocess.run(argv + ["--help"], capture_output=True, text=True, timeout=60)
    if done.returncode != 0:
        sys.exit(f"{' '.join(argv)} --help failed ({done.returncode}): {done.stderr}")
    return done.stdout


def help_options(argv):
    """{'--name': takes a value} from a CLI11 help text's Options section."""
    options = {}
    for line in run_help(argv).split("\n"):
        m = re.match(r"^  (-\S+)( [A-Z]{3,})?", line)
        if m:
            for name in m.group(1).split(","):
                if name.startswith("--"):
                    options[name] = m.group(2) is not None
    if "--help" not in options:
        sys.exit(f"no options found in {' '.join(argv)} --help")
    return options


def subcommands(nimbus):
    text = run_help([nimbus]).split("Subcommands:", 1)
    if len(text) != 2:
        sys.exit(f"{nimbus} --help lists no subcommands")
    return re.findall(r"^  ([a-z][\w-]*)\s", text[1], re.M)


def main():
    if len(sys.argv) != 4:
        sys.exit(__doc__)
    root, nimbus, nimbusd = (os.path.abspath(a) for a in sys.argv[1:])
    checker = Checker(root, nimbus, nimbusd)
    problems = checker.run()
    for p in problems:
        print(p)
    c = checker.counts
    print(f"{c['files']} Markdown files: {c['links']} relative links ({c['anchors']} into "
          f"headings), {c['paths']} repository paths, {c['options']} nimbus/nimbusd options; "
          f"{len(problems)} problems")
    return 1 if problems else 0


if __name__ == "__main__":
    sys.exit(main())

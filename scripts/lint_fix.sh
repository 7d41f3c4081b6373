#!/usr/bin/env bash
# Bring the Python sources to ament_flake8's style (setup.cfg [flake8]), in behaviour-preserving
# steps, then report what flake8 still finds. Run it once everybody's edits are committed, review
# the diff (git diff --stat; the test suite), commit it as one "style" commit.
#
# Usage: scripts/lint_fix.sh [--check] [DIR]      (DIR: the repository, default: this one)
#   --check   change nothing: only report what flake8 finds
#   LINT_EXCLUDE=REGEX  leave the paths matching REGEX alone (e.g. files someone is editing)
#
# Steps (ruff and flake8 are pinned in requirements.txt; from .venv (scripts/setup.sh) or PATH):
#   1. ruff format, line length 99, single quotes (flake8-quotes Q000): a formatter that keeps
#      the AST (it checks it), so behaviour is unchanged; it wraps the code lines over 99 columns.
#   2. ruff check --fix of what a formatter leaves: import order in ament's google style (I100,
#      I101, I201: isort with sorting within sections), docstring punctuation (D209, D210, D400,
#      D403, D205 where the summary is one line), whitespace before ':' in slices (E203) that the
#      formatter writes but pycodestyle refuses.
#   3. Comments and docstring lines still over 99 columns are wrapped at a space (text only; a
#      markdown table row, a doctest or a line without a space is left alone); the space the
#      formatter writes before ':' in slices is removed (pycodestyle E203; ruff's E203 allows it).
#   4. flake8 reports what is left (a human decides: long string literals, D401 imperative mood,
#      names shadowing builtins, ...).
# Exit status: 0 when flake8 finds nothing left, 1 when it does (in either mode), 2 for bad usage
# or a missing tool.
set -euo pipefail
check=0
if [ "${1:-}" = "--check" ]; then check=1; shift; fi
here="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
root="$(cd "${1:-$here}" && pwd)"
# the tools: LINT_BIN's, else the checkout's .venv (scripts/setup.sh), else those on PATH (a ROS
# workspace or a system install has no .venv)
tool_path() {
  local name="$1" alt="${2:-}"
  if [ -n "${LINT_BIN:-}" ]; then echo "$LINT_BIN/$name"; return; fi
  if [ -x "$here/.venv/bin/$name" ]; then echo "$here/.venv/bin/$name"; return; fi
  command -v "$name" 2>/dev/null || { [ -n "$alt" ] && command -v "$alt" 2>/dev/null; } || echo "$name"
}
ruff="$(tool_path ruff)"; flake8="$(tool_path flake8)"; python="$(tool_path python python3)"
for tool in "$ruff" "$flake8" "$python"; do
  [ -x "$tool" ] || { echo "lint_fix: $tool missing: pip install the pinned ruff and flake8 of" \
    "requirements.txt, or run scripts/setup.sh" >&2; exit 2; }
done
cd "$root"
# the Python files of the repository (tracked or new, not ignored), outside vendored folders
mapfile -t files < <( (git ls-files -co --exclude-standard -- '*.py' 2>/dev/null || find . -name '*.py') \
  | grep -vE '(^|/)(\.venv|build|install|log|node_modules|firmware)/' \
  | grep -vE "${LINT_EXCLUDE:-^\$}" | sort -u)
[ ${#files[@]} -gt 0 ] || { echo "lint_fix: no Python files under $root" >&2; exit 2; }

ruff_cfg=(
  --config "line-length = 99"
  --config "format.quote-style = 'single'"
  --config "lint.flake8-quotes.inline-quotes = 'single'"
  --config "lint.isort.force-sort-within-sections = true"
  --config "lint.isort.case-sensitive = false"
  --config "lint.isort.order-by-type = false"
  --config "lint.isort.known-first-party = ['ament_formation']"
  --config "lint.pydocstyle.convention = 'pep257'"
)

count() { "$flake8" --no-show-source --statistics "$@" 2>/dev/null | grep -cE '^[^ ]+:[0-9]+:[0-9]+: ' || true; }

if [ "$check" = 0 ]; then
  before="$(count "${files[@]}")"
  echo "lint_fix: flake8 findings before: $before (${#files[@]} files)"
  # 1. formatter: quotes and code lines
  "$ruff" format --quiet "${ruff_cfg[@]}" "${files[@]}"
  # 2. fixes the formatter does not make (D400 adds a period: an "unsafe" fix only to ruff)
  "$ruff" check --quiet --fix --unsafe-fixes --preview --exit-zero --no-cache "${ruff_cfg[@]}" \
    --select I001,Q000,Q001,Q002,Q003,D209,D210,D400,D403,D205,E203,W291,W293 "${files[@]}" >/dev/null
  # 3. comments and docstring lines over 99 columns
  "$python" - "${files[@]}" <<'PY'
import ast
import sys
import textwrap

LIMIT = 99


def docstring_lines(tree):
    """1-based line numbers of docstring bodies (not their first line)."""
    lines = set()
    for node in ast.walk(tree):
        if isinstance(node, (ast.Module, ast.ClassDef, ast.FunctionDef, ast.AsyncFunctionDef)):
            body = node.body
            if body and isinstance(body[0], ast.Expr) and isinstance(body[0].value, ast.Constant) \
                    and isinstance(body[0].value.value, str):
                lines.update(range(body[0].lineno + 1, body[0].end_lineno + 1))
    return lines


def wrap(line, prefix):
    """Split ``line`` (over LIMIT) at spaces; continuation lines start with ``prefix``."""
    head, text = line[:len(prefix)], line[len(prefix):]
    out = textwrap.wrap(text, width=LIMIT - len(prefix), break_long_words=False,
                        break_on_hyphens=False, drop_whitespace=True)
    if len(out) < 2:
        return [line]
    return [head + out[0]] + [prefix + part for part in out[1:]]


def slice_colons(src):
    """Remove the space the formatter writes before ':' in slices (``x[a + 1 :]``: E203)."""
    import io
    import tokenize

    cuts = []   # (row, start col of the space, col of ':')
    stack, prev = [], None
    for tok in tokenize.generate_tokens(io.StringIO(src).readline):
        if tok.type == tokenize.OP and tok.string in '([{':
            stack.append(tok.string)
        elif tok.type == tokenize.OP and tok.string in ')]}':
            stack and stack.pop()
        elif tok.type == tokenize.OP and tok.string == ':' and stack and stack[-1] == '[' \
                and prev is not None and prev.end[0] == tok.start[0] and prev.end[1] < tok.start[1] \
                and (prev.type in (tokenize.NAME, tokenize.NUMBER, tokenize.STRING)
                     or prev.string in ')]}'):   # an operand ends there (not ', :2')
            cuts.append((tok.start[0], prev.end[1], tok.start[1]))
        if tok.type not in (tokenize.NL, tokenize.COMMENT):
            prev = tok
    if not cuts:
        return src
    lines = src.split('\n')
    for row, start, end in sorted(cuts, reverse=True):
        line = lines[row - 1]
        lines[row - 1] = line[:start] + line[end:]
    return '\n'.join(lines)


changed = 0
for path in sys.argv[1:]:
    src = open(path, encoding='utf-8').read()
    try:
        tree = ast.parse(src)
    except SyntaxError:
        continue
    fixed = slice_colons(src)
    if fixed != src and ast.dump(ast.parse(fixed)) == ast.dump(tree):
        src = fixed
    doc = docstring_lines(tree)
    lines = src.split('\n')
    out = []
    for number, line in enumerate(lines, start=1):
        stripped = line.lstrip()
        indent = line[:len(line) - len(stripped)]
        if len(line) <= LIMIT or ' ' not in stripped:
            out.append(line)
        elif stripped.startswith('#') and not stripped.startswith('#!') and 'noqa' not in line:
            marker = '# ' if stripped.startswith('# ') else '#'
            out.extend(wrap(line, indent + marker))
        elif number in doc and not stripped.startswith(('|', '>>>', '...')) \
                and '"""' not in stripped and "'''" not in stripped:
            out.extend(wrap(line, indent))
        else:
            out.append(line)
    new = '\n'.join(out)
    if new != open(path, encoding='utf-8').read():
        ast.parse(new)   # still valid Python
        open(path, 'w', encoding='utf-8').write(new)
        changed += 1
print(f'lint_fix: wrapped long comments/docstring lines in {changed} files')
PY
fi

echo "lint_fix: flake8 findings left, by code:"
"$flake8" --no-show-source --statistics "${files[@]}" 2>/dev/null \
  | grep -E '^[0-9]+ +[A-Z]+[0-9]+ ' | sort -rn || true
left="$(count "${files[@]}")"
echo "lint_fix: flake8 findings left: $left"
[ "$left" = 0 ] || exit 1

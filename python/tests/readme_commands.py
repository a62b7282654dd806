"""The analysis commands a results README gives, as argument lists (imported as
``readme_commands`` by the tests that replay them).

A README's fenced ``bash`` blocks are read line by line, continuation lines joined. A
line of simple assignments (``NAME=value``, several joined by ``;``) defines ``$NAME``
for the lines after it in the same block; ``for NAME in …`` makes ``NAME`` a loop
variable. A command is a line that runs ``python -m MODULE`` or ``python3 -m MODULE``
(after any ``VAR=value`` environment words); it is returned with its arguments and the
file a ``>`` redirects it to (None when it prints to the README). A command that uses a
loop variable is left out — its outputs are checked through the files it wrote — and
one that still holds any other ``$`` fails, so a mistyped variable cannot drop a
command from the test.
"""

from __future__ import annotations

import re
import shlex
from dataclasses import dataclass
from pathlib import Path

ASSIGNMENT = re.compile(r"^([A-Za-z_][A-Za-z0-9_]*)=(\S+)$")
LOOP = re.compile(r"^for ([A-Za-z_][A-Za-z0-9_]*) in ")


@dataclass(frozen=True)
class Command:
    argv: list[str]
    output: Path | None


def readme_commands(readme: Path, module: str) -> list[Command]:
    commands = []
    for block in re.findall(r"```bash\n(.*?)```", readme.read_text(), flags=re.S):
        variables: dict[str, str] = {}
        loops: set[str] = set()
        for line in block.replace("\\\n", " ").splitlines():
            line = line.strip()
            parts = [ASSIGNMENT.match(part.strip()) for part in line.split(";")]
            if all(parts):
                variables.update(m.group(1, 2) for m in parts)
                continue
            if m := LOOP.match(line):
                loops.add(m.group(1))
            if f"-m {module}" not in line:
                continue
            for name, value in sorted(variables.items(), key=lambda kv: -len(kv[0])):
                line = line.replace(f"${name}", value)
            words = shlex.split(line, comments=True)
            while words and ASSIGNMENT.match(words[0]):
                words = words[1:]
            if words[:3] not in (["python", "-m", module], ["python3", "-m", module]):
                continue
            if any(f"${v}" in w for v in loops for w in words):
                continue
            unresolved = [w for w in words if "$" in w]
            if unresolved:
                raise ValueError(f"{readme}: `{line}` uses a variable the block does not define: {unresolved}")
            output = None
            if ">" in words:
                i = words.index(">")
                output, words = Path(words[i + 1]), words[:i]
            commands.append(Command(words[3:], output))
    return commands

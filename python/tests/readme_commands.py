"""The analysis commands a results README gives, as argument lists (imported as
``readme_commands`` by the tests that replay them).

A README's fenced ``bash`` blocks are read line by line, continuation lines joined; a
line of simple assignments (``NAME=value``, several joined by ``;``) defines ``$NAME`` for the lines after
it in the same block. A command is returned with its arguments after
``python -m MODULE`` and the file a ``>`` redirects it to (None when it prints to the
README). Commands that still hold a ``$`` after substitution (loop variables) are left
out; their outputs are checked through the files they wrote.
"""

from __future__ import annotations

import re
import shlex
from dataclasses import dataclass
from pathlib import Path

ASSIGNMENT = re.compile(r"^([A-Za-z_][A-Za-z0-9_]*)=(\S+)$")


@dataclass(frozen=True)
class Command:
    argv: list[str]
    output: Path | None


def readme_commands(readme: Path, module: str) -> list[Command]:
    commands = []
    for block in re.findall(r"```bash\n(.*?)```", readme.read_text(), flags=re.S):
        variables: dict[str, str] = {}
        for line in block.replace("\\\n", " ").splitlines():
            line = line.strip()
            parts = [ASSIGNMENT.match(part.strip()) for part in line.split(";")]
            if all(parts):
                variables.update(m.group(1, 2) for m in parts)
                continue
            for name, value in sorted(variables.items(), key=lambda kv: -len(kv[0])):
                line = line.replace(f"${name}", value)
            words = shlex.split(line, comments=True)
            if words[:3] != ["python", "-m", module] or any("$" in w for w in words):
                continue
            output = None
            if ">" in words:
                i = words.index(">")
                output, words = Path(words[i + 1]), words[:i]
            commands.append(Command(words[3:], output))
    return commands

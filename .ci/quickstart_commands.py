"""Print the commands of the README's Quick start code block, one per line, comments removed."""
import re
import sys

text = open(sys.argv[1], encoding="utf-8").read()
section = re.search(r"^## Quick start\b(.*?)(?=^## )", text, re.S | re.M)
if not section:
    sys.exit("README has no Quick start section")
block = re.search(r"```(?:bash|sh|console)?\n(.*?)```", section.group(1), re.S)
if not block:
    sys.exit("README's Quick start has no code block")
for line in block.group(1).splitlines():
    line = line.split("  #")[0].strip()
    if line and not line.startswith("#"):
        print(line)

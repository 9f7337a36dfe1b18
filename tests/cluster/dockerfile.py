"""A small reader of docker/Dockerfile for the tests: the instructions of each stage, with line
continuations joined and comments dropped. It knows only what the tests ask about (FROM, RUN,
COPY, ENTRYPOINT, CMD, HEALTHCHECK, USER, EXPOSE, WORKDIR)."""
import json
import re
import shlex


class Instruction:
    def __init__(self, line, keyword, args):
        self.line, self.keyword, self.args = line, keyword, args

    def exec_form(self):
        """The argument as a list: a JSON array (exec form), else split as a shell would."""
        text = self.args
        if self.keyword == "HEALTHCHECK":
            text = re.sub(r"^(--\S+\s+)*CMD\s+", "", text)
        if text.lstrip().startswith("["):
            return json.loads(text)
        return shlex.split(text)

    def options(self):
        """The leading --name=value options (COPY --from=build ...)."""
        return dict(re.findall(r"--([a-z-]+)=(\S+)", self.args))

    def __repr__(self):
        return f"line {self.line}: {self.keyword} {self.args}"


class Stage:
    def __init__(self, image, name):
        self.image, self.name, self.instructions = image, name, []

    def all(self, keyword):
        return [i for i in self.instructions if i.keyword == keyword]

    def last(self, keyword):
        found = self.all(keyword)
        assert found, f"stage {self.name or self.image} has no {keyword}"
        return found[-1]

    def copies(self):
        """(from stage or None, source, destination) of every COPY."""
        out = []
        for c in self.all("COPY"):
            words = [w for w in c.args.split() if not w.startswith("--")]
            *sources, dest = words
            out += [(c.options().get("from"), s, dest) for s in sources]
        return out


def parse(path):
    stages = []
    lines = path.read_text().splitlines()
    i = 0
    while i < len(lines):
        start = i + 1
        text = lines[i]
        i += 1
        if not text.strip() or text.lstrip().startswith("#"):
            continue
        while text.rstrip().endswith("\\") and i < len(lines):
            text = text.rstrip()[:-1] + " "
            while i < len(lines) and lines[i].lstrip().startswith("#"):
                i += 1
            if i < len(lines):
                text += lines[i].strip()
                i += 1
        keyword, _, args = text.strip().partition(" ")
        keyword = keyword.upper()
        args = re.sub(r"\s+", " ", args.strip())
        if keyword == "FROM":
            m = re.fullmatch(r"(\S+)(?: AS (\S+))?", args, re.IGNORECASE)
            assert m, f"line {start}: FROM {args}"
            stages.append(Stage(m.group(1), m.group(2)))
            continue
        assert stages, f"line {start}: {keyword} before FROM"
        stages[-1].instructions.append(Instruction(start, keyword, args))
    return stages

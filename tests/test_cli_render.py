"""`restir render` beside --params: the options' defaults and the JSON library's one home."""
import re

from conftest import ROOT

# cJSON is read through renderer/input/json_read.c by the two readers of untrusted JSON
# (docs/architecture.md): no other source names it, the CLI's --params included.
CJSON_HOMES = {"renderer/input/json_read.c", "renderer/input/json_read.h", "renderer/input/scene_load.c",
               "protocol/request.c"}


def test_cjson_has_one_home():
    users = {str(p.relative_to(ROOT)) for layer in ("renderer", "protocol", "server")
             for p in (ROOT / layer).rglob("*.[ch]") if re.search(r"\bcJSON|cjson/", p.read_text())}
    assert users == CJSON_HOMES

"""`/v1/kinds` and `/v1/scenes` (what the dashboard's submission form offers) and the dashboard's static
files at `/ui`, on a real server: scopes, problem+json errors, OpenAPI, security headers."""

from __future__ import annotations

import jsonschema
import pytest

from tests.integration import test_api_server as api
from tests.integration.test_api_server import DatabaseChoice, problem_of
from workers.models.registry import PRESET_NAMES, get_kind, kind_names
from workers.scene.generators.builtin import BUILTIN_SCENES

server = api.server  # fixture


@pytest.fixture(scope="module")
def database() -> DatabaseChoice:
    """SQLite only: nothing here reads the job database beyond the tokens, which the API tests cover."""
    return DatabaseChoice("sqlite", None)


def test_kinds_list_every_registered_kind_with_its_presets_resolved(server):
    with server.client("read") as reader:
        kinds = reader.get("/v1/kinds").json()["items"]
        assert [k["name"] for k in kinds] == kind_names()
        render = reader.get("/v1/kinds/render").json()
    assert render in kinds and render["trains"] is False
    assert [p["name"] for p in render["presets"]] == list(PRESET_NAMES)
    quick = get_kind("render").resolve_config("quick", {}).model_dump(mode="json")
    assert render["presets"][0]["config"] == quick and quick["width"] == 64
    assert render["example_scene"] in BUILTIN_SCENES
    assert {k["name"] for k in kinds if k["trains"]} == {n for n in kind_names() if get_kind(n).method}


def test_a_kind_serves_its_configs_json_schema_which_its_presets_and_no_typo_meet(server):
    with server.client("read") as reader:
        kinds = {k["name"]: k for k in reader.get("/v1/kinds").json()["items"]}
    for name, kind in kinds.items():
        schema = kind["config_schema"]
        assert schema == get_kind(name).config_model.model_json_schema()
        for preset in kind["presets"]:
            jsonschema.validate(preset["config"], schema)
        typo = {"train": {"stpes": 3}} if "train" in schema["properties"] else {"stpes": 3}
        with pytest.raises(jsonschema.ValidationError, match="stpes"):
            jsonschema.validate(typo, schema)
    assert kinds["render"]["config_schema"]["properties"]["spp"]["minimum"] == 1


def test_scenes_list_the_built_in_scenes_with_a_description(server):
    with server.client("read") as reader:
        scenes = reader.get("/v1/scenes").json()["items"]
    assert [s["name"] for s in scenes] == sorted(BUILTIN_SCENES)
    cornell = next(s for s in scenes if s["name"] == "cornell_box")
    assert "mitsuba" in cornell["description"] and "\n" not in cornell["description"]


def test_an_unknown_kind_is_a_404_problem_and_the_catalog_needs_a_token(server):
    with server.client("read") as reader:
        body = problem_of(reader.get("/v1/kinds/no-such-kind"), 404)
    assert "known kinds: " in body["detail"] and "render" in body["detail"]
    with server.client(None) as anonymous:
        for path in ("/v1/kinds", "/v1/kinds/render", "/v1/scenes"):
            problem_of(anonymous.get(path), 401)
        spec = anonymous.get("/openapi.json").json()
    assert {"/v1/kinds", "/v1/kinds/{kind}", "/v1/scenes"} <= set(spec["paths"])
    assert "404" in spec["paths"]["/v1/kinds/{kind}"]["get"]["responses"]
    assert not any(path.startswith("/ui") for path in spec["paths"])


def test_the_dashboard_is_served_at_ui_with_a_strict_content_security_policy(server):
    with server.client(None) as anonymous:
        assert anonymous.get("/ui").headers["location"].endswith("/ui/")
        page = anonymous.get("/ui/")
        script = anonymous.get("/ui/app.js")
        missing = anonymous.get("/ui/no-such-file.js")
    assert page.status_code == 200 and '<script type="module" src="app.js">' in page.text
    policy = page.headers["content-security-policy"]
    assert "script-src 'self'" in policy and "default-src 'none'" in policy and "unsafe" not in policy
    assert page.headers["x-content-type-options"] == "nosniff"
    assert script.headers["content-type"].startswith("text/javascript") and "import" in script.text
    problem_of(missing, 404)

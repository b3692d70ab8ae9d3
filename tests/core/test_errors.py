"""The core's errors: one line for the CLI, a dict for the service, intact across processes."""

from __future__ import annotations

import pickle

from canopy_core.errors import BallNotFound, CaptureError, ConfigError


def test_capture_error_names_file_and_field_in_one_line() -> None:
    error = CaptureError("fx: must be greater than 0", file="views/2/camera.json", view="views/2", field="fx")
    assert str(error) == "views/2/camera.json: fx: must be greater than 0"
    assert error.to_dict() == {
        "code": "invalid_capture",
        "message": "fx: must be greater than 0",
        "view": "views/2",
        "file": "views/2/camera.json",
        "field": "fx",
    }


def test_ball_not_found_names_view_and_colour() -> None:
    error = BallNotFound("only 3 points", view="views/1", color="blue", hint="move closer")
    assert str(error) == "views/1: blue ball: only 3 points. move closer"
    assert error.to_dict()["color"] == "blue"


def test_errors_survive_pickling_with_their_locations() -> None:
    error = BallNotFound("only 3 points", view="views/1", color="blue")
    copy = pickle.loads(pickle.dumps(error))
    assert type(copy) is BallNotFound and copy.to_dict() == error.to_dict() and str(copy) == str(error)


def test_a_hint_follows_its_message_as_a_sentence_of_its_own() -> None:
    assert str(ConfigError("roi.radius_m: too large", hint="see docs")) == "roi.radius_m: too large. see docs"
    asked = ConfigError("metrics.edge: unknown field; did you mean 'edge_px'?", hint="see docs")
    assert str(asked) == "metrics.edge: unknown field; did you mean 'edge_px'? see docs"
    found = BallNotFound("only 3 points.", view="views/1", color="red", hint="re-lay it")
    assert str(found) == "views/1: red ball: only 3 points. re-lay it"

"""Edits of simulated capture folders that tests share: what happens to a ball in the field."""

from __future__ import annotations

import json
from pathlib import Path

import cv2
import numpy as np
from PIL import Image


def take_away_blue_ball(capture: Path, view: str) -> None:
    """Remove the blue ball from a view, as if a foot had kicked it away: through the disc round where it
    lay the camera sees the ground behind it (the level plane under the ball), and every blue pixel is
    painted grey."""
    truth = json.loads((capture / "ground_truth.json").read_text())
    camera = json.loads((capture / view / "camera.json").read_text())
    centre_world = np.array(truth["balls"]["blue"]["center_m"])
    camera_to_world = np.array(truth["views"][view]["camera_to_world"])
    x, y, z = (np.linalg.inv(camera_to_world) @ np.append(centre_world, 1.0))[:3]
    depth_file = capture / view / "depth.png"
    depth = np.asarray(Image.open(depth_file)).copy()
    intrinsics = camera["depth_intrinsics"]
    rows, cols = np.mgrid[: depth.shape[0], : depth.shape[1]]
    u, v = intrinsics["fx"] * x / z + intrinsics["cx"], intrinsics["fy"] * y / z + intrinsics["cy"]
    disc = (cols - u) ** 2 + (rows - v) ** 2 <= (2.0 * intrinsics["fx"] * 0.05 / z) ** 2
    # Each pixel's ray (camera frame, unit depth) meets the plane z = centre - radius (world) at depth t.
    rays = np.stack(
        [
            (cols[disc] - intrinsics["cx"]) / intrinsics["fx"],
            (rows[disc] - intrinsics["cy"]) / intrinsics["fy"],
        ]
    )
    rays = np.vstack([rays, np.ones(rays.shape[1])])
    world_rays = camera_to_world[:3, :3] @ rays
    floor_z = centre_world[2] - truth["balls"]["blue"]["diameter_m"] / 2
    t = (floor_z - camera_to_world[2, 3]) / world_rays[2]
    depth[disc] = np.where(t > 0, np.rint(t * camera["depth_scale"]), 0).astype(depth.dtype)
    Image.fromarray(depth).save(depth_file)
    paint_blue_grey(capture, view)


def paint_blue_grey(capture: Path, view: str) -> None:
    """Paint every blue pixel of a view's colour image grey: the blue ball keeps its shape, not its colour."""
    color_file = next((capture / view).glob("color.*"))
    rgb = np.asarray(Image.open(color_file).convert("RGB")).copy()
    hsv = cv2.cvtColor(rgb, cv2.COLOR_RGB2HSV)
    rgb[(hsv[..., 0] > 95) & (hsv[..., 0] < 135) & (hsv[..., 1] > 80)] = (120, 110, 100)
    Image.fromarray(rgb).save(color_file)


def crop_depth_top(capture: Path, view: str, rows: int) -> None:
    """Cut the top ``rows`` rows off a view's depth image, as a camera with a narrower field of view
    above would take it: the depth intrinsics' height and principal point follow, the colour stays."""
    depth_file = capture / view / "depth.png"
    depth = np.asarray(Image.open(depth_file))
    Image.fromarray(np.ascontiguousarray(depth[rows:])).save(depth_file)
    camera_file = capture / view / "camera.json"
    camera = json.loads(camera_file.read_text())
    camera["depth_intrinsics"]["height"] -= rows
    camera["depth_intrinsics"]["cy"] -= rows
    camera_file.write_text(json.dumps(camera, indent=2))


def turn_to_portrait(capture: Path) -> None:
    """Turn every view a quarter turn clockwise, as a camera held in portrait takes it: images rotated,
    intrinsics swapped to match, and the depth-to-colour transform carried into the turned axes (x' = -y,
    y' = x)."""
    turn = np.eye(4)
    turn[:3, :3] = [[0, -1, 0], [1, 0, 0], [0, 0, 1]]
    for view in sorted((capture / "views").iterdir()):
        for image_file in (view / "depth.png", view / "color.jpg", view / "color.png"):
            if image_file.exists():
                image = np.asarray(Image.open(image_file))
                Image.fromarray(np.ascontiguousarray(np.rot90(image, k=-1))).save(image_file, quality=95)
        camera_file = view / "camera.json"
        camera = json.loads(camera_file.read_text())
        for key in ("depth_intrinsics", "color_intrinsics"):
            if key in camera:
                old = camera[key]
                camera[key] = {
                    "width": old["height"],
                    "height": old["width"],
                    "fx": old["fy"],
                    "fy": old["fx"],
                    "cx": old["height"] - 1 - old["cy"],
                    "cy": old["cx"],
                }
        if "depth_to_color" in camera:
            camera["depth_to_color"] = (turn @ np.array(camera["depth_to_color"]) @ turn.T).tolist()
        camera_file.write_text(json.dumps(camera, indent=2))

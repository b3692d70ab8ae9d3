// The report's 3D viewer: a measurement's fused cloud (world frame, metres, z up) with the marks of
// where H, W and D were read. Uses the service's own copy of three.js (static/vendor/three).
import * as THREE from "three";
import { OrbitControls } from "three/addons/OrbitControls.js";

const H_COLOUR = 0xd62728, W_COLOUR = 0x9467bd, BASE_COLOUR = 0x1f77b4;
const TREE_CLASS = 5; // ASPRS high vegetation: the points H, W and D were read from

function decode(base64, Type) {
  const bytes = Uint8Array.from(atob(base64), (c) => c.charCodeAt(0));
  return new Type(bytes.buffer);
}

// Colours by height: a blue-green-yellow ramp over the cloud's z range.
function heightColours(positions) {
  let low = Infinity, high = -Infinity;
  for (let i = 2; i < positions.length; i += 3) { low = Math.min(low, positions[i]); high = Math.max(high, positions[i]); }
  const colours = new Float32Array(positions.length), colour = new THREE.Color();
  for (let i = 0; i < positions.length; i += 3) {
    const t = (positions[i + 2] - low) / Math.max(high - low, 1e-6);
    colour.setHSL(0.66 - 0.5 * t, 0.85, 0.5);
    colours.set([colour.r, colour.g, colour.b], i);
  }
  return colours;
}

// A mark drawn over the points (no depth test), so the leaves never hide it.
function line(points, colour) {
  const geometry = new THREE.BufferGeometry().setFromPoints(points.map((p) => new THREE.Vector3(...p)));
  const mark = new THREE.Line(geometry, new THREE.LineBasicMaterial({ color: colour, depthTest: false }));
  mark.renderOrder = 1;
  return mark;
}

// The box round the tree's own points (class 5), or round every point when the cloud has no classes.
function treeBox(positions, classes) {
  const box = new THREE.Box3(), point = new THREE.Vector3();
  for (let i = 0; i < positions.length / 3; i++) {
    if (classes && classes[i] !== TREE_CLASS) continue;
    box.expandByPoint(point.fromArray(positions, 3 * i));
  }
  return box;
}

// The marks: the top's vertical (H) from the ground, W's segment at the crown's middle height, the crown
// base as a square round the tree, and D at its corner from the crown base to the top.
function marks(data, box) {
  const group = new THREE.Group(), m = data.marks;
  const [tx, ty, h] = m.top_m, base = m.crown_base_point_m[2];
  const [[ax, ay], [bx, by]] = m.width_ends_m, middle = (h + base) / 2;
  group.add(line([[tx, ty, 0], [tx, ty, h]], H_COLOUR));
  group.add(line([[ax, ay, middle], [bx, by, middle]], W_COLOUR));
  const [x0, y0, x1, y1] = [box.min.x, box.min.y, box.max.x, box.max.y];
  group.add(line([[x0, y0, base], [x1, y0, base], [x1, y1, base], [x0, y1, base], [x0, y0, base]], BASE_COLOUR));
  group.add(line([[x1, y1, base], [x1, y1, h]], 0x000000));
  return group;
}

export function showCloud(canvas, data) {
  const positions = decode(data.positions_b64, Float32Array);
  const rgb = Float32Array.from(decode(data.colors_b64, Uint8Array), (v) => v / 255);
  const byHeight = heightColours(positions);
  const geometry = new THREE.BufferGeometry();
  geometry.setAttribute("position", new THREE.BufferAttribute(positions, 3));
  geometry.setAttribute("color", new THREE.BufferAttribute(rgb, 3));
  const classes = data.classes_b64 ? decode(data.classes_b64, Uint8Array) : null;
  const box = treeBox(positions, classes), centre = box.getCenter(new THREE.Vector3());
  const size = box.getSize(new THREE.Vector3()).length();

  const renderer = new THREE.WebGLRenderer({ canvas, antialias: true, preserveDrawingBuffer: true });
  renderer.setPixelRatio(window.devicePixelRatio);
  const scene = new THREE.Scene();
  scene.background = new THREE.Color(0xffffff);
  const material = new THREE.PointsMaterial({ size: 2, sizeAttenuation: false, vertexColors: true });
  scene.add(new THREE.Points(geometry, material));
  scene.add(marks(data, box));

  const camera = new THREE.PerspectiveCamera(45, 1, 0.01, 100);
  camera.up.set(0, 0, 1);
  camera.position.set(centre.x - 0.9 * size, centre.y - 0.9 * size, centre.z + 0.35 * size);
  const controls = new OrbitControls(camera, canvas);
  controls.target.copy(centre);
  controls.update();

  // Drawn on demand: when the controls move the camera (their "change" event) and when the page resizes.
  function render() {
    const { clientWidth: width, clientHeight: height } = canvas;
    if (canvas.width !== Math.round(width * renderer.getPixelRatio())) {
      renderer.setSize(width, height, false);
      camera.aspect = width / Math.max(height, 1);
      camera.updateProjectionMatrix();
    }
    renderer.render(scene, camera);
  }
  controls.addEventListener("change", render);
  window.addEventListener("resize", render);
  render();

  return {
    colourBy(mode) {
      geometry.setAttribute("color", new THREE.BufferAttribute(mode === "height" ? byHeight : rgb, 3));
      render();
    },
  };
}

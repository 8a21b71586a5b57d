// The part of three.js that report.html's 3D view uses (idbench/report/view3d.js).
// Bundled into three.min.js with esbuild; see THIRD_PARTY.md at the repository root.
export {
  AmbientLight, BufferAttribute, BufferGeometry, Color, DirectionalLight,
  DoubleSide, Float32BufferAttribute, LineBasicMaterial, LineSegments,
  Mesh, MeshBasicMaterial, MeshLambertMaterial, PerspectiveCamera, Points,
  PointsMaterial, Scene, Sphere, Vector3, WebGLRenderer,
} from "three";
export { OrbitControls } from "three/examples/jsm/controls/OrbitControls.js";

// report.html's 3D view: each run's surface per stored step, coloured by its
// displacement error against the truth (idbench/report/scene.py), the truth's
// surface translucent, the depth camera's cloud and frustum, the markers
// (observed, predicted) and the hidden targets (true, predicted, and each
// one's predicted 95% region at the last step). Data come from the
// JSON block #view3d-data (idbench/report/view3d.py); every name or message it
// holds is shown as text (textContent, option.text), never as markup.
(function () {
  "use strict";
  var root = document.getElementById("view3d");
  var source = document.getElementById("view3d-data");
  if (!root || !source) { return; }
  var note = root.querySelector(".view-note");
  function say(text) { note.textContent = text; }
  var data = JSON.parse(source.textContent);
  if (data.problem) {
    root.classList.add("failed");
    say("No 3D view: this folder fails its checks: " + data.problem);
    return;
  }
  if (!data.runs.length) { say(data.empty); return; }
  if (typeof THREE === "undefined") { say("No 3D view: three.js did not load."); return; }

  function bytes(text) {
    var bin = atob(text), out = new Uint8Array(bin.length);
    for (var i = 0; i < bin.length; i++) { out[i] = bin.charCodeAt(i); }
    return out.buffer;
  }
  function scaled(text, scale, Kind) {
    var raw = new Kind(bytes(text)), out = new Float32Array(raw.length);
    for (var i = 0; i < raw.length; i++) { out[i] = raw[i] * scale; }
    return out;
  }
  var cache = {};
  function decoded(kind, index, make) {
    var key = kind + index;
    if (!(key in cache)) { cache[key] = make(); }
    return cache[key];
  }
  function mesh(i) {
    return decoded("m", i, function () {
      var m = data.meshes[i];
      return { v: new Float32Array(bytes(m.vertices)), t: new Uint32Array(bytes(m.triangles)) };
    });
  }
  function moved(item, kind, index) {
    return decoded(kind, index, function () { return scaled(item.disp, item.scale, Int16Array); });
  }
  function cloud(i) {
    return decoded("c", i, function () {
      var c = data.clouds[i], q = new Uint16Array(bytes(c.points));
      var out = new Float32Array(q.length);
      for (var j = 0; j < q.length; j++) { out[j] = c.offset[j % 3] + q[j] * c.scale[j % 3]; }
      return out;
    });
  }

  // colours: the scale's stops (viridis), 255 means "no value" (grey)
  var stops = data.colours;
  function colour(q, out, at) {
    if (q === 255) { out[at] = out[at + 1] = out[at + 2] = 0.6; return; }
    var x = q / 254 * (stops.length - 1), i = Math.min(Math.floor(x), stops.length - 2);
    var f = x - i, a = stops[i], b = stops[i + 1];
    for (var c = 0; c < 3; c++) { out[at + c] = (a[c] + f * (b[c] - a[c])) / 255; }
  }

  var canvas = root.querySelector("canvas");
  var renderer;
  try {
    renderer = new THREE.WebGLRenderer({ canvas: canvas, antialias: true, preserveDrawingBuffer: true });
  } catch (err) {
    say("No 3D view: this browser cannot draw WebGL (" + err.message + "). report.md's stills show the best and the worst run.");
    return;
  }
  renderer.setPixelRatio(1);
  var scene = new THREE.Scene();
  scene.background = new THREE.Color(0xffffff);
  var camera = new THREE.PerspectiveCamera(35, 1.6, 1e-4, 100);
  camera.up.set(0, 0, 1);
  scene.add(new THREE.AmbientLight(0xffffff, 1.3));
  var light = new THREE.DirectionalLight(0xffffff, 1.8);
  camera.add(light);
  light.position.set(0.3, 0.6, 1);
  scene.add(camera);
  var controls = new THREE.OrbitControls(camera, canvas);
  controls.addEventListener("change", draw);

  var model = new THREE.Mesh(new THREE.BufferGeometry(), new THREE.MeshLambertMaterial({
    vertexColors: true, side: THREE.DoubleSide }));
  var truth = new THREE.Mesh(new THREE.BufferGeometry(), new THREE.MeshBasicMaterial({
    color: 0x555555, transparent: true, opacity: 0.18, depthWrite: false, side: THREE.DoubleSide }));
  var points = new THREE.Points(new THREE.BufferGeometry(), new THREE.PointsMaterial({
    size: 4, sizeAttenuation: false, vertexColors: true }));
  var frustum = new THREE.LineSegments(new THREE.BufferGeometry(), new THREE.LineBasicMaterial({ color: 0x222222 }));
  [model, truth, points, frustum].forEach(function (o) { scene.add(o); });
  // markers and targets: drawn through the surface (targets lie inside the body)
  var legend = data.legend;
  function dots(key, size, order) {
    var o = new THREE.Points(new THREE.BufferGeometry(), new THREE.PointsMaterial({
      color: new THREE.Color(legend[key]), size: size, sizeAttenuation: false,
      transparent: true, depthTest: false, depthWrite: false }));
    o.renderOrder = order;  // a prediction drawn over its (larger) truth
    o.visible = false;
    scene.add(o);
    return o;
  }
  var sets = {
    "markers-observed": dots("markers-observed", 10, 2),
    "markers-predicted": dots("markers-predicted", 6, 3),
    "targets-true": dots("targets-true", 11, 2),
    "targets-predicted": dots("targets-predicted", 7, 3),
  };
  var regions = new THREE.Mesh(new THREE.BufferGeometry(), new THREE.MeshBasicMaterial({
    color: new THREE.Color(legend["targets-predicted"]), transparent: true, opacity: 0.3,
    depthTest: false, depthWrite: false, side: THREE.DoubleSide }));
  regions.renderOrder = 1;
  regions.visible = false;
  scene.add(regions);
  var sphere = (function () {  // the unit sphere, latitude by longitude
    var rows = 12, cols = 24, v = [], t = [], i, j;
    for (i = 0; i <= rows; i++) {
      for (j = 0; j <= cols; j++) {
        var th = Math.PI * i / rows, ph = 2 * Math.PI * j / cols;
        v.push(Math.sin(th) * Math.cos(ph), Math.sin(th) * Math.sin(ph), Math.cos(th));
      }
    }
    for (i = 0; i < rows; i++) {
      for (j = 0; j < cols; j++) {
        var a = i * (cols + 1) + j, b = a + cols + 1;
        t.push(a, b, a + 1, b, b + 1, a + 1);
      }
    }
    return { v: v, t: t };
  })();

  function deformed(rest, disp, at, n) {
    var out = new Float32Array(n * 3);
    for (var i = 0; i < n * 3; i++) { out[i] = rest[i] + disp[at + i]; }
    return out;
  }
  function setSurface(object, m, position) {
    var g = new THREE.BufferGeometry();
    g.setAttribute("position", new THREE.BufferAttribute(position, 3));
    g.setIndex(new THREE.BufferAttribute(m.t, 1));
    g.computeVertexNormals();
    object.geometry.dispose();
    object.geometry = g;
    return g;
  }

  // the positions of step s (n points a step), those not NaN (not observed)
  function setDots(object, all, s, n) {
    var out = [];
    for (var i = 0; i < n; i++) {
      var a = (s * n + i) * 3;
      if (isFinite(all[a]) && isFinite(all[a + 1]) && isFinite(all[a + 2])) {
        out.push(all[a], all[a + 1], all[a + 2]);
      }
    }
    var g = new THREE.BufferGeometry();
    g.setAttribute("position", new THREE.BufferAttribute(new Float32Array(out), 3));
    object.geometry.dispose();
    object.geometry = g;
    object.visible = out.length > 0;
  }
  // each region: its centre plus its axes (row-major 3 x 3) times the unit sphere
  function setRegions(list) {
    var nv = sphere.v.length / 3, pos = new Float32Array(list.length * nv * 3), idx = [];
    list.forEach(function (r, k) {
      var c = r.centre, A = r.axes;
      for (var i = 0; i < nv; i++) {
        var x = sphere.v[3 * i], y = sphere.v[3 * i + 1], z = sphere.v[3 * i + 2];
        for (var d = 0; d < 3; d++) {
          pos[3 * (k * nv + i) + d] = c[d] + A[3 * d] * x + A[3 * d + 1] * y + A[3 * d + 2] * z;
        }
      }
      sphere.t.forEach(function (v) { idx.push(k * nv + v); });
    });
    var g = new THREE.BufferGeometry();
    g.setAttribute("position", new THREE.BufferAttribute(pos, 3));
    g.setIndex(idx);
    regions.geometry.dispose();
    regions.geometry = g;
    regions.visible = list.length > 0;
  }
  function positions(run, kind, key) {
    return decoded(kind + key, state.run, function () { return new Float32Array(bytes(run[kind][key])); });
  }

  var state = { run: 0, step: 0, framed: false };
  var selects = {}, slider = root.querySelector("#view3d-step");
  var stepLabel = root.querySelector(".view-step"), info = root.querySelector(".view-info");
  var message = root.querySelector(".view-message");
  var layers = {
    truth: root.querySelector("#view3d-truth"),
    cloud: root.querySelector("#view3d-cloud"),
    camera: root.querySelector("#view3d-camera"),
    markers: root.querySelector("#view3d-markers"),
    targets: root.querySelector("#view3d-targets"),
  };

  function show() {
    var run = data.runs[state.run], m = mesh(run.mesh), n = m.v.length / 3;
    var s = Math.min(state.step, run.steps.length - 1);
    var disp = moved(run, "r", state.run);
    var g = setSurface(model, m, deformed(m.v, disp, s * n * 3, n));
    var colours = new Float32Array(n * 3), err = run.err ? new Uint8Array(bytes(run.err)) : null;
    for (var i = 0; i < n; i++) { colour(err ? err[s * n + i] : 255, colours, 3 * i); }
    g.setAttribute("color", new THREE.BufferAttribute(colours, 3));
    var k = run.steps[s];
    layers.truth.disabled = run.truth < 0;
    layers.cloud.disabled = run.cloud < 0;
    layers.camera.disabled = !run.camera;
    truth.visible = false;
    if (run.truth >= 0 && layers.truth.checked) {
      var t = data.truths[run.truth], tm = mesh(t.mesh), tn = tm.v.length / 3, j = t.steps.indexOf(k);
      if (j >= 0) {
        setSurface(truth, tm, deformed(tm.v, moved(t, "t", run.truth), j * tn * 3, tn));
        truth.visible = true;
      }
    }
    points.visible = false;
    if (run.cloud >= 0 && layers.cloud.checked) {
      var c = cloud(run.cloud), np = c.length / run.steps.length / 3;
      var bits = new Uint8Array(bytes(run.outliers)), pc = new Float32Array(np * 3);
      for (var p = 0; p < np; p++) {
        var b = s * np + p, out = (bits[b >> 3] >> (7 - (b & 7))) & 1;
        pc[3 * p] = out ? 0.85 : 0.1; pc[3 * p + 1] = out ? 0.1 : 0.2; pc[3 * p + 2] = out ? 0.1 : 0.6;
      }
      var pg = new THREE.BufferGeometry();
      pg.setAttribute("position", new THREE.BufferAttribute(c.subarray(s * np * 3, (s + 1) * np * 3), 3));
      pg.setAttribute("color", new THREE.BufferAttribute(pc, 3));
      points.geometry.dispose();
      points.geometry = pg;
      points.visible = true;
    }
    frustum.visible = false;
    if (run.camera && layers.camera.checked) { drawFrustum(run.camera); frustum.visible = true; }
    layers.markers.disabled = !run.markers;
    layers.targets.disabled = !run.targets;
    Object.keys(sets).forEach(function (key) { sets[key].visible = false; });
    regions.visible = false;
    if (run.markers && layers.markers.checked) {
      setDots(sets["markers-observed"], positions(run, "markers", "observed"), s, run.markers.n);
      setDots(sets["markers-predicted"], positions(run, "markers", "predicted"), s, run.markers.n);
    }
    if (run.targets && layers.targets.checked) {
      setDots(sets["targets-true"], positions(run, "targets", "true"), s, run.targets.n);
      setDots(sets["targets-predicted"], positions(run, "targets", "predicted"), s, run.targets.n);
      if (s === run.steps.length - 1) { setRegions(run.targets.regions); }
    }
    Array.prototype.forEach.call(root.querySelectorAll(".view-legend [data-layer]"), function (item) {
      var kind = item.getAttribute("data-layer").split("-")[0];
      item.style.opacity = run[kind] ? "1" : "0.35";
    });
    slider.max = String(run.steps.length - 1);
    slider.value = String(s);
    stepLabel.textContent = "step " + k + " of " + run.total;
    info.textContent = run.title;
    message.textContent = run.message;
    if (!state.framed) { frame(g); state.framed = true; }
    draw();
  }

  function drawFrustum(cam) {
    var o = new THREE.Vector3(cam[0], cam[1], cam[2]), look = new THREE.Vector3(cam[3], cam[4], cam[5]);
    var dir = look.clone().sub(o), depth = dir.length() * 1.15;
    dir.normalize();
    var up = Math.abs(dir.z) > 0.9 ? new THREE.Vector3(0, 1, 0) : new THREE.Vector3(0, 0, 1);
    var right = dir.clone().cross(up).normalize(), upv = right.clone().cross(dir).normalize();
    var h = Math.tan(cam[6] * Math.PI / 360) * depth, w = h * cam[7], pts = [];
    var corners = [[-1, -1], [1, -1], [1, 1], [-1, 1]].map(function (c) {
      return o.clone().addScaledVector(dir, depth).addScaledVector(right, c[0] * w).addScaledVector(upv, c[1] * h);
    });
    corners.forEach(function (c, i) {
      pts.push(o, c, c, corners[(i + 1) % 4]);
    });
    var arr = new Float32Array(pts.length * 3);
    pts.forEach(function (p, i) { arr[3 * i] = p.x; arr[3 * i + 1] = p.y; arr[3 * i + 2] = p.z; });
    var g = new THREE.BufferGeometry();
    g.setAttribute("position", new THREE.BufferAttribute(arr, 3));
    frustum.geometry.dispose();
    frustum.geometry = g;
  }

  function frame(g) {
    g.computeBoundingSphere();
    var sphere = g.boundingSphere, d = sphere.radius / Math.sin(camera.fov * Math.PI / 360) * 0.95;
    controls.target.copy(sphere.center);
    camera.position.copy(sphere.center).add(new THREE.Vector3(0.55, -0.75, 0.38).normalize().multiplyScalar(d));
    camera.near = d / 100; camera.far = d * 100;
    camera.updateProjectionMatrix();
    controls.update();
  }

  function resize() {
    var w = canvas.clientWidth || 800, h = canvas.clientHeight || 480;
    renderer.setSize(w, h, false);
    camera.aspect = w / h;
    camera.updateProjectionMatrix();
  }
  var frames = 0;
  function draw() {
    renderer.render(scene, camera);
    root.setAttribute("data-drawn", String(++frames));  // frames drawn so far
  }

  // choosing a run: one select per axis; the run matching most choices wins
  function choose(wanted, first) {
    var best = 0, score = -1;
    data.runs.forEach(function (run, i) {
      var sc = 0;
      data.axes.forEach(function (axis, a) {
        if (wanted[axis] === undefined) { return; }
        if (run.labels[a] === wanted[axis]) { sc += axis === first ? 1000 : 1; }
      });
      if (sc > score) { score = sc; best = i; }
    });
    return best;
  }
  function current() {
    var out = {};
    data.axes.forEach(function (axis) { out[axis] = selects[axis].value; });
    return out;
  }
  function select(i) {
    state.run = i;
    data.axes.forEach(function (axis, a) { selects[axis].value = data.runs[i].labels[a]; });
    show();
  }
  var bar = root.querySelector(".view-choices");
  data.axes.forEach(function (axis, a) {
    var label = document.createElement("label"), sel = document.createElement("select");
    label.textContent = axis + " ";
    sel.setAttribute("data-axis", axis);
    var seen = {};
    data.runs.forEach(function (run) {
      var v = run.labels[a];
      if (seen[v]) { return; }
      seen[v] = true;
      var opt = document.createElement("option");
      opt.value = v; opt.text = v;
      sel.appendChild(opt);
    });
    sel.addEventListener("change", function () { select(choose(current(), axis)); });
    label.appendChild(sel);
    bar.appendChild(label);
    selects[axis] = sel;
  });
  slider.addEventListener("input", function () { state.step = Number(slider.value); show(); });
  Object.keys(layers).forEach(function (name) { layers[name].addEventListener("change", show); });
  root.querySelector("#view3d-reset").addEventListener("click", function () { state.framed = false; show(); });

  // the summary table: clicking a row shows its runs (the seed kept where it can)
  var table = document.getElementById("summary");
  if (table) {
    var heads = Array.prototype.map.call(table.tHead.rows[0].cells, function (th) { return th.title; });
    Array.prototype.forEach.call(table.tBodies[0].rows, function (tr) {
      tr.classList.add("viewable");
      tr.addEventListener("click", function () {
        var wanted = current();
        data.axes.forEach(function (axis) {
          var col = heads.indexOf(axis);
          if (col >= 0) { wanted[axis] = tr.cells[col].getAttribute("data-value"); }
        });
        select(choose(wanted, "estimator"));
        root.scrollIntoView({ block: "nearest" });
      });
    });
  }

  // the colour bar
  var gradient = stops.map(function (c, i) {
    return "rgb(" + c.join(",") + ") " + (100 * i / (stops.length - 1)).toFixed(1) + "%";
  });
  root.querySelector(".view-bar").style.background = "linear-gradient(to right, " + gradient.join(", ") + ")";
  var ticks = root.querySelectorAll(".view-ticks span");
  Array.prototype.forEach.call(ticks, function (span, i) {
    span.textContent = (data.top * i / (ticks.length - 1)).toPrecision(3);
  });

  resize();
  window.addEventListener("resize", function () { resize(); draw(); });
  var asked = /(?:^#|&)run=([^&]+)/.exec(window.location.hash);
  var start = 0;
  if (asked) {
    data.runs.forEach(function (run, i) { if (run.id === decodeURIComponent(asked[1])) { start = i; } });
  }
  state.step = data.runs[start].steps.length - 1;
  select(start);
})();

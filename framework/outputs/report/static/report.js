// surgiplan's report and live viewer: one classic script over three.js (the global THREE).
// The data is the JSON in #surgiplan-data (see surgiplan/outputs/report/data.py); in live mode the page
// gets the same shapes over a websocket from `surgiplan view --live`. window.surgiplan exposes what the
// page drew (counts), its state and a few controls, for people in the console and for the browser tests.
"use strict";
(function () {
  const S = (window.surgiplan = {
    ready: false,
    errors: [],
    counts: {},
    frames: 0,
    revision: THREE.REVISION,
  });
  window.addEventListener("error", (e) => S.errors.push(String(e.message || e)));

  // ------------------------------------------------------------------ data
  function decode(p) {
    if (!p) return null;
    const bin = atob(p.b64);
    const bytes = new Uint8Array(bin.length);
    for (let i = 0; i < bin.length; i++) bytes[i] = bin.charCodeAt(i);
    return p.dtype === "u32" ? new Uint32Array(bytes.buffer) : new Float32Array(bytes.buffer);
  }
  const DATA = JSON.parse(document.getElementById("surgiplan-data").textContent);
  const LIVE = !!DATA.live;
  let unit = DATA.run.length_unit || "m";
  let unitScale = DATA.run.unit_scale || 1;
  const SHOW_ALL = /show=all/.test(location.hash);

  function len(m, digits) {
    if (m === null || m === undefined || !isFinite(m)) return "—";
    return `${(+m / unitScale).toPrecision(digits || 4).replace(/\.?0+$/, "")} ${unit}`;
  }
  function num(v) {
    if (typeof v !== "number") return String(v);
    if (Number.isInteger(v)) return v.toLocaleString("en");
    const a = Math.abs(v);
    return a !== 0 && (a < 1e-3 || a >= 1e6) ? v.toExponential(3) : (+v.toPrecision(4)).toString();
  }
  function metricValue(key, v) {
    if (Array.isArray(v)) {  // lists: each item formatted as its key says (lengths in the run's unit), at most 8
      if (v.length === 0) return "none";
      const items = v.slice(0, 8).map((x) => metricValue(key, x));
      const joined = items.join(v.every((x) => typeof x === "number" || x === null) ? ", " : "; ");
      return v.length > 8 ? `${joined}; … (${v.length} in all)` : joined;
    }
    if (v !== null && typeof v === "object") {  // a small table: name value, name value
      const text = Object.entries(v).map(([k2, x]) => `${k2.replace(/_(m|s|Pa|J)$/, "")} ${metricValue(k2, x)}`).join(", ");
      return text.length > 400 ? text.slice(0, 400) + "…" : text;
    }
    if (typeof v === "number" && /_m$/.test(key) && !/_Jm$/.test(key)) return len(v);
    if (typeof v === "number" && /_s$/.test(key)) return `${num(v)} s`;
    if (typeof v === "number" && /_Pa$/.test(key)) return v >= 1e3 ? `${num(v / 1e3)} kPa` : `${num(v)} Pa`;
    if (typeof v === "number" && /_J$/.test(key)) return `${num(v)} J`;
    if (typeof v === "number" || typeof v === "string" || typeof v === "boolean") return num(v);
    if (v === null) return "—";
    const text = JSON.stringify(v);
    return text.length > 400 ? text.slice(0, 400) + "…" : text;
  }
  function el(tag, attrs, ...children) {
    const e = document.createElement(tag);
    for (const [k, v] of Object.entries(attrs || {})) {
      if (k === "class") e.className = v;
      else if (k === "style") e.style.cssText = v;
      else if (k.startsWith("on")) e.addEventListener(k.slice(2), v);
      else e.setAttribute(k, v);
    }
    for (const c of children) if (c !== null && c !== undefined) e.append(c);
    return e;
  }
  function badgeClass(status) {
    if (["solved", "completed", "converged", "succeeded", "followed"].includes(status)) return "badge ok";
    if (["stopped", "refused", "no_path", "failed", "timeout", "skipped", "not_run", "incomplete"].includes(status)) return "badge warn";
    // unsafe, invalid_result, error, interrupted: red
    return "badge bad";
  }

  // ------------------------------------------------------------------ three.js scene
  const view = document.getElementById("view");
  // live: no multisampling, so a machine without a GPU (software WebGL) spends less of the CPU the stage needs
  const renderer = new THREE.WebGLRenderer({ antialias: !LIVE, preserveDrawingBuffer: true });
  renderer.setPixelRatio(window.devicePixelRatio || 1);
  view.insertBefore(renderer.domElement, view.firstChild);
  // the live view's frame budget. Without a GPU the 3D view, the 2D overlay and the text are drawn and composited on
  // the CPUs the watched stage needs. Beside a guide attempt at 100 samples/s at ordinary priority (2 cores,
  // benchmarks/bench_live_delay.py --quick, 8 s, five interleaved pairs), a page redrawing at the display's rate
  // delayed 18-108 samples beyond 2 ms, one drawing 30 frames a second 5-10. So on a software renderer the live
  // view draws at most SOFTWARE_FPS frames a second, each with the newest sample (its cues' sample-to-pixels p99
  // stays under 50 ms). `surgiplan view --live --fps N` sets the budget (0: every frame the display offers).
  const SOFTWARE_FPS = 30;
  const RENDERER = (() => {
    try {
      const gl = renderer.getContext(), info = gl.getExtension("WEBGL_debug_renderer_info");
      return String(gl.getParameter(info ? info.UNMASKED_RENDERER_WEBGL : gl.RENDERER));
    } catch (e) { return ""; }
  })();
  const SOFTWARE_WEBGL = /swiftshader|llvmpipe|softpipe|software/i.test(RENDERER);
  const LIVE_FPS = !LIVE ? 0 : typeof DATA.fps === "number" ? DATA.fps : SOFTWARE_WEBGL ? SOFTWARE_FPS : 0;
  const FRAME_MS = LIVE_FPS > 0 ? 1000 / LIVE_FPS : 0;
  const scene = new THREE.Scene();
  scene.background = new THREE.Color(0xf7f7f4);
  const camera = new THREE.PerspectiveCamera(40, 1, 1e-4, 1e4);
  camera.up.set(0, 0, 1);
  const controls = new THREE.OrbitControls(camera, renderer.domElement);
  controls.addEventListener("change", () => requestRender());
  scene.add(new THREE.HemisphereLight(0xffffff, 0x8a8a8a, 2.2));
  const sun = new THREE.DirectionalLight(0xffffff, 1.6);
  sun.position.set(0.4, -0.8, 1.0);
  scene.add(sun);
  const world = new THREE.Group();
  scene.add(world);

  let dirty = true;
  // the live view's 2D overlay: redrawn when a sample arrives, reprojected when the view changed (viewVersion)
  let overlayDirty = false, drawOverlay = null, viewVersion = 0;
  function requestRender() {
    dirty = true;
    viewVersion++;
  }
  function resize() {
    const w = Math.max(1, view.clientWidth), h = Math.max(1, view.clientHeight);
    renderer.setSize(w, h, false);
    const overlayCanvas = document.getElementById("overlay");
    overlayCanvas.width = renderer.domElement.width;
    overlayCanvas.height = renderer.domElement.height;
    camera.aspect = w / h;
    camera.updateProjectionMatrix();
    requestRender();
  }
  new ResizeObserver(resize).observe(view);

  // scale of markers: a fraction of the workspace
  let R = 0.001;
  let bounds = null; // THREE.Box3 of the workspace

  function colour(hex) {
    return new THREE.Color(hex);
  }
  const RED = colour("#d62728");
  const CRITICAL = colour("#ff7f0e");
  const GHOST = "#17becf"; // the expert ghost
  function lineGeometry(points) {
    const g = new THREE.BufferGeometry();
    g.setAttribute("position", new THREE.BufferAttribute(points, 3));
    return g;
  }
  function ghostLabel(g) {
    return `${g.trainee || "expert"}, attempt ${g.attempt}${typeof g.score === "number" ? ", score " + g.score.toFixed(0) : ""}`;
  }

  // a tube along a polyline (n points), coloured per point; parallel-transported frames, `sides` around
  function tube(points, radius, colours, sides) {
    sides = sides || 8;
    const n = points.length / 3;
    if (n < 2) return null;
    const pos = new Float32Array(n * sides * 3), nor = new Float32Array(n * sides * 3);
    const col = colours ? new Float32Array(n * sides * 3) : null;
    const p = (i) => new THREE.Vector3(points[3 * i], points[3 * i + 1], points[3 * i + 2]);
    let normal = null, tangent = new THREE.Vector3(1, 0, 0);
    const binormal = new THREE.Vector3(), dir = new THREE.Vector3();
    for (let i = 0; i < n; i++) {
      const t = p(Math.min(i + 1, n - 1)).sub(p(Math.max(i - 1, 0)));
      if (t.lengthSq() > 0) tangent = t.normalize();
      if (normal === null) {
        normal = Math.abs(tangent.z) < 0.9 ? new THREE.Vector3(0, 0, 1) : new THREE.Vector3(1, 0, 0);
      }
      normal.addScaledVector(tangent, -normal.dot(tangent));
      if (normal.lengthSq() < 1e-12) normal = Math.abs(tangent.z) < 0.9 ? new THREE.Vector3(0, 0, 1) : new THREE.Vector3(1, 0, 0);
      normal.addScaledVector(tangent, -normal.dot(tangent)).normalize();
      binormal.crossVectors(tangent, normal);
      const c = p(i);
      for (let s = 0; s < sides; s++) {
        const a = (2 * Math.PI * s) / sides;
        dir.copy(normal).multiplyScalar(Math.cos(a)).addScaledVector(binormal, Math.sin(a));
        const o = 3 * (i * sides + s);
        pos[o] = c.x + radius * dir.x; pos[o + 1] = c.y + radius * dir.y; pos[o + 2] = c.z + radius * dir.z;
        nor[o] = dir.x; nor[o + 1] = dir.y; nor[o + 2] = dir.z;
        if (col) { col[o] = colours[3 * i]; col[o + 1] = colours[3 * i + 1]; col[o + 2] = colours[3 * i + 2]; }
      }
    }
    const index = new Uint32Array((n - 1) * sides * 6);
    let k = 0;
    for (let i = 0; i < n - 1; i++)
      for (let s = 0; s < sides; s++) {
        const a = i * sides + s, b = i * sides + ((s + 1) % sides), c = a + sides, d = b + sides;
        index[k++] = a; index[k++] = c; index[k++] = b;
        index[k++] = b; index[k++] = c; index[k++] = d;
      }
    const g = new THREE.BufferGeometry();
    g.setAttribute("position", new THREE.BufferAttribute(pos, 3));
    g.setAttribute("normal", new THREE.BufferAttribute(nor, 3));
    if (col) g.setAttribute("color", new THREE.BufferAttribute(col, 3));
    g.setIndex(new THREE.BufferAttribute(index, 1));
    g.userData.sides = sides;
    return g;
  }

  function sphere(at, radius, hex, opts) {
    const m = new THREE.Mesh(
      new THREE.SphereGeometry(radius, 16, 12),
      new THREE.MeshLambertMaterial(Object.assign({ color: colour(hex) }, opts || {}))
    );
    m.position.set(at[0], at[1], at[2]);
    return m;
  }

  function cumulative(points) {
    const n = points.length / 3, s = new Float64Array(n);
    for (let i = 1; i < n; i++) {
      const dx = points[3 * i] - points[3 * i - 3], dy = points[3 * i + 1] - points[3 * i - 2], dz = points[3 * i + 2] - points[3 * i - 1];
      s[i] = s[i - 1] + Math.hypot(dx, dy, dz);
    }
    return s;
  }
  // the stretch of a polyline between arc lengths s0 and s1
  function stretch(points, s, s0, s1) {
    const out = [];
    const at = (i, f) => [0, 1, 2].map((c) => points[3 * i + c] + f * (points[3 * i + 3 + c] - points[3 * i + c]));
    for (let i = 0; i < s.length - 1; i++) {
      const a = s[i], b = s[i + 1];
      if (b < s0 || a > s1) continue;
      const L = b - a || 1;
      if (!out.length) out.push(...at(i, Math.max(0, (s0 - a) / L)));
      if (b <= s1) out.push(points[3 * i + 3], points[3 * i + 4], points[3 * i + 5]);
      else { out.push(...at(i, (s1 - a) / L)); break; }
    }
    return new Float32Array(out);
  }

  const pickable = []; // meshes the pointer can name
  const stageObjects = {}; // name -> {layer: Object3D}
  function addLayer(stage, layer, object, visible) {
    stageObjects[stage] = stageObjects[stage] || {};
    (stageObjects[stage][layer] = stageObjects[stage][layer] || []).push(object);
    object.visible = SHOW_ALL || visible !== false;
    world.add(object);
    return object;
  }

  // ------------------------------------------------------------------ the workspace
  let obstacleGroup = new THREE.Group();
  world.add(obstacleGroup);
  function buildScene(sc) {
    world.remove(obstacleGroup);
    obstacleGroup = new THREE.Group();
    world.add(obstacleGroup);
    if (!sc) return;
    const [lo, hi] = sc.bounds;
    bounds = new THREE.Box3(new THREE.Vector3(...lo), new THREE.Vector3(...hi));
    const size = bounds.getSize(new THREE.Vector3());
    R = 0.008 * Math.min(size.x, size.y, size.z);
    const box = new THREE.LineSegments(
      new THREE.EdgesGeometry(new THREE.BoxGeometry(size.x, size.y, size.z)),
      new THREE.LineBasicMaterial({ color: 0x9a9a9a })
    );
    box.position.copy(bounds.getCenter(new THREE.Vector3()));
    box.userData = { kind: "bounds" };
    obstacleGroup.add(box);
    const material = new THREE.MeshLambertMaterial({ color: 0x9aa3ad, transparent: true, opacity: 0.62, depthWrite: false, side: THREE.DoubleSide });
    // a merged mesh of many obstacles (a scan's voxels): front faces only, writing depth, without outlines. Seen
    // through both sides with no depth written, thousands of overlapping translucent boxes blend layer on layer at
    // every pixel (without a GPU a frame of 10,000 boxes took 0.73 s, against 0.17 s for a few obstacles; now
    // 0.29 s: benchmarks/bench_scale.py); the nearest face still lets the paths inside show through
    const manyMaterial = new THREE.MeshLambertMaterial({ color: 0x9aa3ad, transparent: true, opacity: 0.62, side: THREE.FrontSide });
    for (const o of sc.obstacles) {
      let g = new THREE.BufferGeometry();
      g.setAttribute("position", new THREE.BufferAttribute(decode(o.vertices), 3));
      g.setIndex(new THREE.BufferAttribute(decode(o.faces), 1));
      g = g.toNonIndexed();
      g.computeVertexNormals();
      const many = (o.count || 1) > 1; // a merged mesh of many obstacles (outputs/merged.py)
      const mesh = new THREE.Mesh(g, many ? manyMaterial : material);
      mesh.userData = { kind: "obstacle", name: o.name, count: o.count || 1, label: many ? `${o.name}: ${o.count} obstacles, merged` : `obstacle ${o.name} (${o.kind})` };
      mesh.renderOrder = 2;
      obstacleGroup.add(mesh);
      pickable.push(mesh);
      if (many) continue;
      const edges = new THREE.LineSegments(new THREE.EdgesGeometry(g, 25), new THREE.LineBasicMaterial({ color: 0x5f6870 }));
      edges.userData = { kind: "obstacle-edges" };
      obstacleGroup.add(edges);
    }
    for (const [name, at] of Object.entries(sc.points || {})) {
      const m = sphere(at, 1.3 * R, "#6b6b6b");
      m.userData = { kind: "point", name, label: `point ${name}` };
      obstacleGroup.add(m);
      pickable.push(m);
    }
    document.getElementById("show-obstacles").onchange = (e) => {
      obstacleGroup.visible = e.target.checked;
      requestRender();
    };
  }

  // ------------------------------------------------------------------ stages
  const timeStages = []; // stages with a time slider: {name, kind: "timeline"|"mesh", count, set(i), ...}

  function pathColours(n, base, low) {
    const c = new Float32Array(3 * n), b = colour(base);
    for (let i = 0; i < n; i++) {
      const red = low && ((i > 0 && low[i - 1]) || (i < n - 1 && low[i]));
      const k = red ? RED : b;
      c[3 * i] = k.r; c[3 * i + 1] = k.g; c[3 * i + 2] = k.b;
    }
    return c;
  }

  function drawPath(st, path, radius, opts) {
    const tips = decode(path.tips);
    const low = path.low ? decode(path.low) : null;
    const g = tube(tips, radius, pathColours(tips.length / 3, st.colour, low));
    if (!g) return null;
    const mesh = new THREE.Mesh(g, new THREE.MeshLambertMaterial(Object.assign({ vertexColors: true }, opts || {})));
    mesh.userData = { kind: "path", name: st.name, stage: st.name, tips, clearance: path.clearance ? decode(path.clearance) : null, threshold: st.threshold };
    pickable.push(mesh);
    return mesh;
  }

  // a zone a device keeps the motion out of (or in): its outline extruded from z[0] to z[1], walls and rims
  function drawZone(st, z) {
    const xy = decode(z.outline), n = xy.length / 2, [z0, z1] = z.z, walls = [], rims = [];
    for (let i = 0; i < n; i++) {
      const j = (i + 1) % n, a = [xy[2 * i], xy[2 * i + 1]], b = [xy[2 * j], xy[2 * j + 1]];
      walls.push(a[0], a[1], z0, b[0], b[1], z0, b[0], b[1], z1, a[0], a[1], z0, b[0], b[1], z1, a[0], a[1], z1);
      rims.push(a[0], a[1], z0, b[0], b[1], z0, a[0], a[1], z1, b[0], b[1], z1);
    }
    const hex = z.inclusion ? "#2ca02c" : "#d62728", group = new THREE.Group();
    const g = new THREE.BufferGeometry();
    g.setAttribute("position", new THREE.Float32BufferAttribute(walls, 3));
    const wall = new THREE.Mesh(g, new THREE.MeshBasicMaterial({ color: colour(hex), transparent: true, opacity: z.inclusion ? 0.03 : 0.1, depthWrite: false, side: THREE.DoubleSide }));
    wall.userData = { kind: "zone", stage: st.name, label: `${st.name}: geofence ${z.inclusion ? "inclusion" : "exclusion"} zone${z.name ? " (" + z.name + ")" : ""}` };
    if (!z.inclusion) pickable.push(wall);
    const r = new THREE.BufferGeometry();
    r.setAttribute("position", new THREE.Float32BufferAttribute(rims, 3));
    const rim = new THREE.LineSegments(r, new THREE.LineBasicMaterial({ color: colour(hex), transparent: true, opacity: 0.6 }));
    rim.userData = { kind: "zone-edges" };
    group.add(wall, rim);
    return group;
  }

  function drawRoadmap(st, r) {
    const g = new THREE.BufferGeometry();
    if (r.kind === "roadmap") {
      g.setAttribute("position", new THREE.BufferAttribute(decode(r.nodes), 3));
      g.setIndex(new THREE.BufferAttribute(decode(r.edges), 1));
    } else {
      const points = decode(r.points), starts = decode(r.starts);
      const n = points.length / 3, paths = starts.length - 1;
      const index = new Uint32Array(2 * Math.max(0, n - paths));
      let k = 0;
      for (let j = 0; j < paths; j++) for (let i = starts[j]; i + 1 < starts[j + 1]; i++) { index[k++] = i; index[k++] = i + 1; }
      g.setAttribute("position", new THREE.BufferAttribute(points, 3));
      g.setIndex(new THREE.BufferAttribute(index.subarray(0, k), 1));
    }
    const lines = new THREE.LineSegments(g, new THREE.LineBasicMaterial({ color: colour(st.colour), transparent: true, opacity: r.kind === "roadmap" ? 0.28 : 0.22, depthWrite: false }));
    lines.userData = { kind: r.kind === "roadmap" ? "roadmap" : "pathset", stage: st.name, segments: g.index.count / 2, count: r.count };
    return lines;
  }

  // viridis, 9 stops
  const VIRIDIS = ["#440154", "#472d7b", "#3b528b", "#2c728e", "#21918c", "#28ae80", "#5ec962", "#addc30", "#fde725"].map(colour);
  function viridis(f, out) {
    f = Math.min(1, Math.max(0, f)) * (VIRIDIS.length - 1);
    const i = Math.min(VIRIDIS.length - 2, Math.floor(f)), w = f - i;
    out.r = VIRIDIS[i].r + w * (VIRIDIS[i + 1].r - VIRIDIS[i].r);
    out.g = VIRIDIS[i].g + w * (VIRIDIS[i + 1].g - VIRIDIS[i].g);
    out.b = VIRIDIS[i].b + w * (VIRIDIS[i + 1].b - VIRIDIS[i].b);
    return out;
  }

  function drawMesh(st, m) {
    const tri = decode(m.triangles), positions = decode(m.positions), stress = m.stress ? decode(m.stress) : null;
    const T = tri.length / 3, N = m.nodes;
    const g = new THREE.BufferGeometry();
    const pos = new Float32Array(T * 9), col = new Float32Array(T * 9);
    g.setAttribute("position", new THREE.BufferAttribute(pos, 3));
    g.setAttribute("color", new THREE.BufferAttribute(col, 3));
    const mesh = new THREE.Mesh(g, new THREE.MeshLambertMaterial({ vertexColors: true, side: THREE.DoubleSide }));
    let [lo, hi] = m.stress_range || [0, 1];
    const logScale = lo > 0 && hi / lo > 50;
    const scale = (v) => (logScale ? Math.log(v / lo) / Math.log(hi / lo) : (v - lo) / (hi - lo || 1));
    const c = new THREE.Color();
    function setFrame(f) {
      f = Math.max(0, Math.min(m.frames - 1, f | 0));
      const base = f * N * 3;
      for (let t = 0; t < T; t++) {
        if (stress) viridis(scale(stress[f * T + t]), c);
        else c.set(0xe8a0a0);
        for (let v = 0; v < 3; v++) {
          const node = tri[3 * t + v], o = 9 * t + 3 * v;
          pos[o] = positions[base + 3 * node]; pos[o + 1] = positions[base + 3 * node + 1]; pos[o + 2] = positions[base + 3 * node + 2];
          col[o] = c.r; col[o + 1] = c.g; col[o + 2] = c.b;
        }
      }
      g.attributes.position.needsUpdate = true;
      g.attributes.color.needsUpdate = true;
      g.computeVertexNormals();
      g.computeBoundingSphere();
      g.computeBoundingBox();
      mesh.userData.frame = f;
      requestRender();
    }
    setFrame(m.frames - 1);
    mesh.userData = Object.assign(mesh.userData, { kind: "mesh", stage: st.name, name: st.name, label: `tissue of ${st.name}`, triangles: T });
    pickable.push(mesh);
    if (m.area) {
      const ap = decode(m.area.points), vis = decode(m.area.visible);
      const ac = new Float32Array(ap.length);
      for (let i = 0; i < vis.length; i++) { const k = vis[i] ? colour("#2ca02c") : RED; ac[3 * i] = k.r; ac[3 * i + 1] = k.g; ac[3 * i + 2] = k.b; }
      const ag = new THREE.BufferGeometry();
      ag.setAttribute("position", new THREE.BufferAttribute(ap, 3));
      ag.setAttribute("color", new THREE.BufferAttribute(ac, 3));
      const pts = new THREE.Points(ag, new THREE.PointsMaterial({ size: 4, sizeAttenuation: false, vertexColors: true }));
      pts.userData = { kind: "area", stage: st.name };
      addLayer(st.name, "mesh", pts);
    }
    return { mesh, setFrame, logScale, lo, hi };
  }

  function bisect(t, x) {
    let a = 0, b = t.length - 1;
    if (x <= t[0]) return 0;
    if (x >= t[b]) return b;
    while (b - a > 1) { const m = (a + b) >> 1; if (t[m] <= x) a = m; else b = m; }
    return a;
  }

  function buildStage(st, index) {
    const holder = {};
    if (st.path && st.stage !== "execute" && st.stage !== "guide") {
      const m = drawPath(st, st.path, R);
      if (m) addLayer(st.name, "path", m);
      const tips = decode(st.path.tips), s = cumulative(tips);
      for (const r of st.critical || []) {
        const part = stretch(tips, s, r.start, r.end);
        const g = tube(part, 2.6 * R, null, 12);
        if (!g) continue;
        const c = new THREE.Mesh(g, new THREE.MeshBasicMaterial({ color: CRITICAL, transparent: true, opacity: 0.35, depthWrite: false }));
        c.userData = { kind: "critical", stage: st.name, label: `${st.name}: critical region, ${len(r.end - r.start)} long, min clearance ${len(r.min_clearance)}${r.obstacles && r.obstacles.length ? ", at " + r.obstacles.join(", ") : ""}` };
        pickable.push(c);
        addLayer(st.name, "critical", c);
      }
    }
    for (const key of ["start", "goal"]) {
      if (!st[key]) continue;
      const m = sphere(st[key], 3 * R, key === "start" ? "#2b2b2b" : "#d4a017");
      m.userData = { kind: key, stage: st.name, label: `${st.name}: ${key}` };
      pickable.push(m);
      addLayer(st.name, "path", m);
    }
    if (st.roadmap) addLayer(st.name, "roadmap", drawRoadmap(st, st.roadmap), false);
    for (const z of st.zones || []) addLayer(st.name, "geofence", drawZone(st, z));
    if (st.mesh) {
      const m = drawMesh(st, st.mesh);
      addLayer(st.name, "mesh", m.mesh);
      holder.mesh = m;
      if (st.mesh.frames > 1 || st.stage === "simulate" || st.mesh.stress) {
        timeStages.push({
          name: st.name, kind: "mesh", count: st.mesh.frames, times: st.mesh.times, timeLabel: st.mesh.time_label,
          series: st.mesh.max_stress ? [{ name: "largest stress", unit: "Pa", values: st.mesh.max_stress, colour: "#7b3294" }] : [],
          events: [], mesh: m,
          set(i) { m.setFrame(i); return { frame: i, t: st.mesh.times[i], max_stress: st.mesh.max_stress ? st.mesh.max_stress[i] : null }; },
        });
      }
    }
    if (st.timeline) {
      const tl = st.timeline;
      const t = decode(tl.t), tip = decode(tl.tip);
      const commanded = tl.commanded ? decode(tl.commanded) : null;
      const expert = tl.ghost ? decode(tl.ghost) : null;
      const clearance = tl.clearance ? decode(tl.clearance) : null, deviation = tl.deviation ? decode(tl.deviation) : null;
      if (st.reference) {
        const ref = decode(st.reference.tips);
        const g = tube(ref, 0.8 * R, null, 8);
        if (g) {
          const m = new THREE.Mesh(g, new THREE.MeshLambertMaterial({ color: colour("#555555"), transparent: true, opacity: 0.45, depthWrite: false }));
          m.userData = { kind: "reference", stage: st.name, label: `${st.name}: ${st.stage === "guide" ? "recommended" : "planned"} path (${st.reference.name})` };
          pickable.push(m);
          addLayer(st.name, "path", m);
        }
      }
      if (st.path) {
        const m = drawPath(st, st.path, 0.6 * R, { transparent: true, opacity: 0.5 });
        if (m) { m.userData.label = `${st.name}: ${st.stage === "guide" ? "followed" : "executed"} path`; addLayer(st.name, "path", m); }
      }
      // the trail up to the current time, and the instrument
      const trailGeometry = new THREE.BufferGeometry();
      trailGeometry.setAttribute("position", new THREE.BufferAttribute(tip, 3));
      const trail = new THREE.Line(trailGeometry, new THREE.LineBasicMaterial({ color: colour(st.colour) }));
      trail.userData = { kind: "trail", stage: st.name };
      addLayer(st.name, "timeline", trail);
      const marker = sphere([tip[0], tip[1], tip[2]], 4.5 * R, "#ff7f0e");
      marker.userData = { kind: "instrument", stage: st.name, label: `${st.name}: instrument` };
      pickable.push(marker);
      addLayer(st.name, "timeline", marker);
      let ghost = null;
      if (commanded) {
        ghost = sphere([commanded[0], commanded[1], commanded[2]], 4.5 * R, "#1f6fb4", { transparent: true, opacity: 0.45, depthWrite: false });
        ghost.userData = { kind: "commanded", stage: st.name, label: `${st.name}: commanded` };
        addLayer(st.name, "timeline", ghost);
      }
      let expertMarker = null;
      if (expert) {
        // the expert ghost: an expert's recorded attempt, where they were at this sample's progress
        const who = st.ghost ? ghostLabel(st.ghost) : "expert";
        if (st.ghost) {
          const path = new THREE.Line(lineGeometry(decode(st.ghost.tips)), new THREE.LineBasicMaterial({ color: colour(GHOST), transparent: true, opacity: 0.55 }));
          path.userData = { kind: "ghost-path", stage: st.name };
          addLayer(st.name, "ghost", path);
        }
        expertMarker = sphere([expert[0], expert[1], expert[2]], 4.5 * R, GHOST, { transparent: true, opacity: 0.8, depthWrite: false });
        expertMarker.userData = { kind: "ghost", stage: st.name, label: `${st.name}: expert ghost (${who})` };
        pickable.push(expertMarker);
        addLayer(st.name, "ghost", expertMarker);
      }
      const series = [];
      if (clearance) series.push({ name: "clearance", unit: "m", values: clearance, colour: "#2ca02c", threshold: st.threshold });
      if (deviation) series.push({ name: "deviation", unit: "m", values: deviation, colour: "#9467bd" });
      timeStages.push({
        name: st.name, kind: "timeline", count: t.length, times: t, timeLabel: tl.time_unit === "s" ? "time" : "sample",
        timeUnit: tl.time_unit, series, events: tl.events || [], marker, ghost,
        set(i) {
          i = Math.max(0, Math.min(t.length - 1, i | 0));
          marker.position.set(tip[3 * i], tip[3 * i + 1], tip[3 * i + 2]);
          if (ghost) ghost.position.set(commanded[3 * i], commanded[3 * i + 1], commanded[3 * i + 2]);
          if (expertMarker) expertMarker.position.set(expert[3 * i], expert[3 * i + 1], expert[3 * i + 2]);
          trailGeometry.setDrawRange(0, i + 1);
          requestRender();
          return {
            index: i, t: t[i], tip: [tip[3 * i], tip[3 * i + 1], tip[3 * i + 2]],
            commanded: commanded ? [commanded[3 * i], commanded[3 * i + 1], commanded[3 * i + 2]] : null,
            ghost: expert ? [expert[3 * i], expert[3 * i + 1], expert[3 * i + 2]] : null,
            clearance: clearance ? clearance[i] : null, deviation: deviation ? deviation[i] : null,
          };
        },
      });
    }
    return holder;
  }

  // ------------------------------------------------------------------ the side panel
  function stagePanel(st) {
    const layers = el("div", { class: "layers" });
    for (const layer of Object.keys(stageObjects[st.name] || {})) {
      const objs = stageObjects[st.name][layer];
      const label = layer === "roadmap" && st.roadmap
        ? (st.roadmap.kind === "roadmap" ? `roadmap (${st.roadmap.count.toLocaleString("en")} milestones, ${st.roadmap.edge_count.toLocaleString("en")} edges)` : `${st.roadmap.count.toLocaleString("en")} stored paths`)
        : layer;
      const box = el("input", { type: "checkbox", "data-stage": st.name, "data-layer": layer });
      box.checked = objs[0].visible;
      box.onchange = () => { S.show(st.name, layer, box.checked); };
      layers.append(el("label", {}, box, " " + label));
    }
    const table = el("table", { class: "metrics" });
    for (const [k, v] of st.metrics || []) table.append(el("tr", {}, el("td", {}, k), el("td", {}, metricValue(k, v))));
    const images = el("div", { class: "images" });
    for (const f of st.images || []) images.append(el("a", { href: f, target: "_blank" }, el("img", { src: f, alt: f, loading: "lazy" })));
    const open = (st.images || []).length < 3 ? { open: "" } : {};
    return el("details", Object.assign({ class: "stage", "data-stage": st.name }, open.open === undefined ? {} : { open: "" }),
      el("summary", {}, el("span", { class: "sw", style: `background:${st.colour}` }), `${st.name} `,
        el("span", { class: "meta", style: "font-weight:400;color:#666" }, `${st.stage} · ${st.plugin} `), el("span", { class: badgeClass(st.status) }, st.status)),
      st.message ? el("div", { class: "message" }, st.message) : null,
      ...(st.warnings || []).map((w) => el("div", { class: "message warning" }, "warning: " + w)),
      layers, table, images);
  }

  function legend(stages) {
    const L = document.getElementById("legend");
    L.innerHTML = "";
    L.style.display = "block";
    for (const st of stages) L.append(el("span", { class: "sw", style: `background:${st.colour}` }), st.name);
    L.append(el("span", { class: "sw", style: "background:#d62728" }), "below threshold",
      el("span", { class: "sw", style: "background:#ff7f0e;opacity:.6" }), "critical region",
      el("span", { class: "sw", style: "background:#2b2b2b" }), "start",
      el("span", { class: "sw", style: "background:#d4a017" }), "goal");
    if (stages.some((st) => st.ghost)) L.append(el("span", { class: "sw", style: `background:${GHOST}` }), "expert ghost");
  }

  // ------------------------------------------------------------------ the time bar
  const timebar = document.getElementById("timebar"), slider = document.getElementById("slider");
  const select = document.getElementById("timestage"), label = document.getElementById("timelabel");
  const chart = document.getElementById("chart"), eventsBox = document.getElementById("events");
  let active = null, state = null, playing = false, playStart = 0, playFrom = 0;

  function fmtT(ts, i) {
    if (ts.kind === "mesh") return `${ts.timeLabel} ${num(ts.times[i])} (state ${i + 1} of ${ts.count})`;
    return ts.timeUnit === "s" ? `t = ${(+ts.times[i]).toFixed(3)} s` : `sample ${i + 1} of ${ts.count}`;
  }
  function setIndex(i) {
    if (!active) return null;
    i = Math.max(0, Math.min(active.count - 1, i | 0));
    slider.value = String(i);
    state = Object.assign({ stage: active.name }, active.set(i));
    state.index = i;
    let text = fmtT(active, i);
    if (state.clearance !== undefined && state.clearance !== null) text += ` · clearance ${len(state.clearance, 3)}`;
    if (state.deviation !== undefined && state.deviation !== null) text += ` · deviation ${len(state.deviation, 3)}`;
    if (state.max_stress !== undefined && state.max_stress !== null) text += ` · largest stress ${metricValue("x_Pa", state.max_stress)}`;
    label.textContent = text;
    drawChart();
    return state;
  }
  function choose(name) {
    active = timeStages.find((ts) => ts.name === name) || null;
    if (!active) { timebar.style.display = "none"; return; }
    timebar.style.display = "block";
    select.value = active.name;
    slider.max = String(active.count - 1);
    eventsBox.innerHTML = "";
    for (const e of active.events) {
      eventsBox.append(el("div", { onclick: () => { if (e.t !== null) setIndex(bisect(active.times, e.t)); } },
        `${e.t === null ? "" : (+e.t).toFixed(3) + " s "}`, el("b", {}, e.kind), e.message ? `: ${e.message}` : ""));
    }
    const cb = document.getElementById("colourbar");
    if (active.kind === "mesh" && active.mesh && active.mesh.hi !== undefined) {
      cb.style.display = "block";
      const cv = cb.querySelector("canvas"), ctx = cv.getContext("2d"), c = new THREE.Color();
      for (let x = 0; x < cv.width; x++) { viridis(x / (cv.width - 1), c); ctx.fillStyle = `#${c.getHexString()}`; ctx.fillRect(x, 0, 1, cv.height); }
      document.getElementById("colourbar-label").textContent = `largest principal stress${active.mesh.logScale ? " (log scale)" : ""}`;
      document.getElementById("cb-min").textContent = metricValue("x_Pa", active.mesh.lo);
      document.getElementById("cb-max").textContent = metricValue("x_Pa", active.mesh.hi);
    } else cb.style.display = "none";
    setIndex(active.kind === "mesh" ? active.count - 1 : 0);
  }
  function drawChart() {
    const ctx = chart.getContext("2d");
    const w = (chart.width = chart.clientWidth * (window.devicePixelRatio || 1)), h = (chart.height = 90 * (window.devicePixelRatio || 1));
    ctx.clearRect(0, 0, w, h);
    if (!active) return;
    const t = active.times, n = active.count;
    const t0 = t[0], t1 = t[n - 1] === t0 ? t0 + 1 : t[n - 1];
    const X = (v) => 40 + ((v - t0) / (t1 - t0)) * (w - 50);
    ctx.font = `${10 * (window.devicePixelRatio || 1)}px sans-serif`;
    let y = 12;
    for (const s of active.series) {
      let lo = Infinity, hi = -Infinity;
      for (let i = 0; i < n; i++) if (isFinite(s.values[i])) { lo = Math.min(lo, s.values[i]); hi = Math.max(hi, s.values[i]); }
      if (s.threshold) { lo = Math.min(lo, s.threshold); hi = Math.max(hi, s.threshold); }
      if (!isFinite(lo)) continue;
      lo = Math.min(lo, 0);
      const Y = (v) => h - 8 - ((v - lo) / (hi - lo || 1)) * (h - 20);
      ctx.strokeStyle = s.colour; ctx.lineWidth = 1.5; ctx.beginPath();
      for (let i = 0; i < n; i++) { const px = X(t[i]), py = Y(s.values[i]); if (i) ctx.lineTo(px, py); else ctx.moveTo(px, py); }
      ctx.stroke();
      if (s.threshold) { ctx.setLineDash([4, 3]); ctx.strokeStyle = "#d62728"; ctx.beginPath(); ctx.moveTo(X(t0), Y(s.threshold)); ctx.lineTo(X(t1), Y(s.threshold)); ctx.stroke(); ctx.setLineDash([]); }
      ctx.fillStyle = s.colour;
      ctx.fillText(`${s.name} (max ${s.unit === "m" ? len(hi, 3) : metricValue("x_Pa", hi)})`, 44, y);
      y += 12;
    }
    ctx.strokeStyle = "#d62728";
    // labels that would overlap the one before are raised a line (events close in time, e.g. a breach and its action)
    let labelEnd = -Infinity, labelRow = 0;
    for (const e of active.events) if (e.t !== null && e.t !== undefined) {
      ctx.beginPath(); ctx.moveTo(X(e.t), 0); ctx.lineTo(X(e.t), h); ctx.stroke(); ctx.fillStyle = "#d62728";
      labelRow = X(e.t) + 2 < labelEnd ? (labelRow + 1) % 4 : 0;
      ctx.fillText(e.kind, X(e.t) + 2, h - 2 - 12 * labelRow);
      labelEnd = Math.max(labelRow ? labelEnd : -Infinity, X(e.t) + 2 + ctx.measureText(e.kind).width + 4);
    }
    if (state && state.index !== undefined) { ctx.strokeStyle = "#000"; ctx.beginPath(); ctx.moveTo(X(t[state.index]), 0); ctx.lineTo(X(t[state.index]), h); ctx.stroke(); }
  }
  slider.addEventListener("input", () => { playing = false; setIndex(+slider.value); });
  select.addEventListener("change", () => choose(select.value));
  chart.addEventListener("click", (ev) => {
    if (!active) return;
    const r = chart.getBoundingClientRect(), f = (ev.clientX - r.left - 40 / (window.devicePixelRatio || 1)) / (r.width - 50 / (window.devicePixelRatio || 1));
    const t = active.times, tt = t[0] + f * (t[active.count - 1] - t[0]);
    setIndex(bisect(t, tt));
  });
  document.getElementById("play").addEventListener("click", () => {
    if (!active) return;
    playing = !playing;
    playStart = performance.now();
    playFrom = +slider.value >= active.count - 1 ? 0 : +slider.value;
  });

  // ------------------------------------------------------------------ views, hover
  function frame(direction) {
    const box = bounds ? bounds.clone() : new THREE.Box3().setFromObject(world);
    const content = new THREE.Box3();
    world.traverse((o) => { if (o.visible && (o.isMesh || o.isLine || o.isPoints) && o.userData.kind && o.userData.kind !== "obstacle-edges") content.expandByObject(o); });
    if (!content.isEmpty()) box.union(content);
    if (box.isEmpty()) box.set(new THREE.Vector3(-1, -1, -1), new THREE.Vector3(1, 1, 1));
    const centre = box.getCenter(new THREE.Vector3()), size = box.getSize(new THREE.Vector3());
    const radius = 0.5 * size.length() || 1;
    const d = radius / Math.sin(THREE.MathUtils.degToRad(camera.fov / 2)) * 1.02;
    const dirs = { iso: [-0.55, -1.0, 0.8], top: [0, -0.0001, 1], front: [0, -1, 0.0001], side: [1, 0, 0.0001] };
    const v = new THREE.Vector3(...(dirs[direction] || dirs.iso)).normalize();
    camera.position.copy(centre).addScaledVector(v, d);
    camera.near = d / 1000; camera.far = d * 100;
    camera.updateProjectionMatrix();
    controls.target.copy(centre);
    controls.update();
    requestRender();
  }
  for (const b of document.querySelectorAll("#toolbar button")) b.addEventListener("click", () => frame(b.dataset.view));

  const tooltip = document.getElementById("tooltip");
  const raycaster = new THREE.Raycaster();
  function describe(hit) {
    const u = hit.object.userData;
    if (u.kind === "path") {
      const sides = hit.object.geometry.userData.sides || 8;
      const i = Math.floor(hit.face.a / sides);
      const c = u.clearance ? u.clearance[Math.min(i, u.clearance.length - 1)] : null;
      return `${u.label || "path " + u.name}${c !== null ? `: clearance ${len(c, 3)}${u.threshold ? (c < u.threshold ? " (below the " : " (threshold ") + len(u.threshold, 3) + ")" : ""}` : ""}`;
    }
    return u.label || u.name || u.kind;
  }
  function visibleChain(o) { for (; o; o = o.parent) if (!o.visible) return false; return true; }
  function hover(clientX, clientY) {
    const r = renderer.domElement.getBoundingClientRect();
    const p = new THREE.Vector2(((clientX - r.left) / r.width) * 2 - 1, -((clientY - r.top) / r.height) * 2 + 1);
    raycaster.setFromCamera(p, camera);
    const hits = raycaster.intersectObjects(pickable.filter(visibleChain), false);
    if (!hits.length) { tooltip.style.display = "none"; S.hovered = null; return null; }
    const text = describe(hits[0]);
    tooltip.textContent = text;
    tooltip.style.left = `${clientX + 12}px`;
    tooltip.style.top = `${clientY + 12}px`;
    tooltip.style.display = "block";
    S.hovered = text;
    return text;
  }
  renderer.domElement.addEventListener("pointermove", (e) => hover(e.clientX, e.clientY));
  renderer.domElement.addEventListener("pointerleave", () => { tooltip.style.display = "none"; S.hovered = null; });

  // ------------------------------------------------------------------ the API (console, tests)
  function countDrawn() {
    const c = { obstacles: 0, obstacle_outlines: 0, paths: 0, points: 0, critical_regions: 0, roadmaps: 0, roadmap_edges: 0, path_sets: 0, stored_paths: 0, meshes: 0, mesh_triangles: 0, timelines: 0, ghosts: 0, zones: 0 };
    world.traverse((o) => {
      const u = o.userData;
      if (u.kind === "obstacle") c.obstacles += u.count || 1;
      else if (u.kind === "obstacle-edges") c.obstacle_outlines++;
      else if (u.kind === "path") c.paths++;
      else if (u.kind === "point") c.points++;
      else if (u.kind === "critical") c.critical_regions++;
      else if (u.kind === "roadmap") { c.roadmaps++; c.roadmap_edges += u.segments; }
      else if (u.kind === "pathset") { c.path_sets++; c.stored_paths += u.count; }
      else if (u.kind === "mesh") { c.meshes++; c.mesh_triangles += u.triangles; }
      else if (u.kind === "instrument") c.timelines++;
      else if (u.kind === "ghost") c.ghosts++;
      else if (u.kind === "zone") c.zones++;
    });
    S.counts = c;
    // how each obstacle mesh is drawn (tests): a merged mesh of many is front faces only, writing depth
    S.obstacleMaterials = () => {
      const out = [];
      world.traverse((o) => {
        if (o.userData.kind !== "obstacle") return;
        const m = o.material;
        out.push({ count: o.userData.count || 1, side: m.side === THREE.FrontSide ? "front" : m.side === THREE.BackSide ? "back" : "double", depthWrite: m.depthWrite, transparent: m.transparent });
      });
      return out;
    };
    const parts = [`drew ${c.obstacles} obstacles`, `${c.paths} paths`];
    if (c.critical_regions) parts.push(`${c.critical_regions} critical regions`);
    if (c.roadmaps) parts.push(`${c.roadmaps} roadmaps (${c.roadmap_edges.toLocaleString("en")} edges)`);
    if (c.path_sets) parts.push(`${c.stored_paths.toLocaleString("en")} stored paths`);
    if (c.meshes) parts.push(`${c.meshes} tissue meshes (${c.mesh_triangles.toLocaleString("en")} triangles)`);
    if (c.timelines) parts.push(`${c.timelines} timelines`);
    if (c.ghosts) parts.push(`${c.ghosts} expert ghost${c.ghosts > 1 ? "s" : ""}`);
    if (c.zones) parts.push(`${c.zones} geofence zones`);
    document.getElementById("counts").textContent = parts.join(", ");
    return c;
  }
  S.show = (stage, layer, on) => {
    for (const o of (stageObjects[stage] || {})[layer] || []) o.visible = on;
    for (const b of document.querySelectorAll(`input[data-stage="${CSS.escape(stage)}"][data-layer="${layer}"]`)) b.checked = on;
    requestRender();
  };
  S.setView = (v) => frame(v);
  S.timeStages = () => timeStages.map((t) => ({ name: t.name, kind: t.kind, count: t.count }));
  S.chooseStage = (name) => { choose(name); return S.state(); };
  S.setIndex = (i) => setIndex(i);
  S.setFraction = (f) => setIndex(Math.round(f * ((active ? active.count : 1) - 1)));
  S.state = () => (state ? JSON.parse(JSON.stringify(state)) : null);
  S.hover = hover;
  S.screenOf = (p) => {
    const v = new THREE.Vector3(p[0], p[1], p[2]).project(camera), r = renderer.domElement.getBoundingClientRect();
    return { x: r.left + ((v.x + 1) / 2) * r.width, y: r.top + ((1 - v.y) / 2) * r.height, inside: Math.abs(v.x) <= 1 && Math.abs(v.y) <= 1 && v.z < 1 };
  };
  S.renderedFrames = () => S.frames;
  // the time (ms) of each of ``n`` frames drawn as the camera turns about the target, each waited for (a pixel
  // read back): how interactive the page is with what it draws (benchmarks/bench_scale.py)
  S.frameTimes = (n) => {
    const gl = renderer.getContext(), px = new Uint8Array(4), times = [];
    const offset = camera.position.clone().sub(controls.target);
    for (let i = 0; i < n; i++) {
      offset.applyAxisAngle(new THREE.Vector3(0, 0, 1), (2 * Math.PI) / Math.max(n, 1));
      camera.position.copy(controls.target).add(offset);
      camera.lookAt(controls.target);
      const t0 = performance.now();
      renderer.render(scene, camera);
      gl.readPixels(0, 0, 1, 1, gl.RGBA, gl.UNSIGNED_BYTE, px);
      times.push(performance.now() - t0);
    }
    requestRender();
    return times;
  };

  // ------------------------------------------------------------------ render loop
  let liveDirty = false, deferred = false;
  // when the live view last drew, and the live text's redraw (set by buildLive: true when it drew)
  let lastDrawn = -Infinity, drawText = null;
  const PIXEL = new Uint8Array(4);
  const overlay = document.getElementById("overlay");
  function loop(now) {
    requestAnimationFrame(loop);
    // within the live view's budget (FRAME_MS, above): a frame early by under a millisecond is on time (the
    // display's frames come 16.7 ms apart, so at 30 a second every other one)
    if (FRAME_MS && now - lastDrawn < FRAME_MS - 1) return;
    if (LIVE && dirty && S.live.pending.length && drawOverlay && !deferred) {
      // a sample waits: its cues first, on their own frame; the 3D view (slow without a GPU) on the next one
      overlayDirty = false;
      deferred = true;
      lastDrawn = now;
      S.live.frames++;
      cuesDrawn(drawOverlay(), false);
      return;
    }
    deferred = false;
    if (playing && active) {
      const span = active.times[active.count - 1] - active.times[0];
      const seconds = (performance.now() - playStart) / 1000;
      const target = active.kind === "timeline" && active.timeUnit === "s" ? active.times[playFrom] + seconds : playFrom + seconds * Math.max(1, active.count / 8);
      const i = active.kind === "timeline" && active.timeUnit === "s" ? bisect(active.times, target) : Math.floor(target);
      setIndex(Math.min(i, active.count - 1));
      if (i >= active.count - 1 || (span <= 0)) playing = false;
    }
    let drew = false;
    if (dirty) {
      dirty = false;
      renderer.render(scene, camera);
      S.frames++;
      drew = true;
      if (!S.ready) { S.ready = true; S.loadMs = performance.now(); }
    }
    if (!LIVE) return;
    if ((overlayDirty || drew) && drawOverlay) { overlayDirty = false; cuesDrawn(drawOverlay(), drew); drew = true; }
    if (drawText && drawText()) drew = true;
    if (drew) { lastDrawn = now; S.live.frames++; }
  }
  // after the live view's overlay is drawn (at the instrument's pixel ``tip``): count the update, and each waiting
  // sample's latency; with #latency the pixels are read back first, so they exist
  function cuesDrawn(tip, drew) {
    if (liveDirty) { liveDirty = false; S.live.updates++; S.live.updateTimes.push(performance.now()); if (S.live.updateTimes.length > 4000) S.live.updateTimes.splice(0, 2000); }
    if (!S.live.pending.length) return;
    if (S.live.measurePixels) {
      if (tip) overlay.getContext("2d").getImageData(Math.max(0, tip[0] | 0), Math.max(0, tip[1] | 0), 1, 1);
      if (drew) { const gl = renderer.getContext(); gl.readPixels(0, 0, 1, 1, gl.RGBA, gl.UNSIGNED_BYTE, PIXEL); }
    }
    const now = performance.timeOrigin + performance.now();
    for (const wall of S.live.pending) S.live.cueLatency.push(now - 1000 * wall);
    S.live.pending.length = 0;
    if (S.live.cueLatency.length > 200000) S.live.cueLatency.splice(0, 100000);
  }

  // ------------------------------------------------------------------ header
  function header(run) {
    document.getElementById("title").textContent = run.name || "surgiplan";
    const st = document.getElementById("status");
    st.textContent = run.status || (LIVE ? "live" : "");
    st.className = badgeClass(run.status || "");
    document.getElementById("meta").textContent = [run.pipeline_file, run.surgiplan_version ? `surgiplan ${run.surgiplan_version}` : "", `lengths in ${unit}`].filter(Boolean).join(" · ");
    document.getElementById("revision").textContent = THREE.REVISION;
  }

  // ------------------------------------------------------------------ the static report
  function buildReport() {
    header(DATA.run);
    buildScene(DATA.scene);
    if (!DATA.scene) {
      let box = new THREE.Box3();
      for (const st of DATA.stages) for (const key of ["path", "mesh"]) if (st[key]) {
        const a = decode(key === "path" ? st.path.tips : st.mesh.positions);
        for (let i = 0; i < a.length; i += 3) box.expandByPoint(new THREE.Vector3(a[i], a[i + 1], a[i + 2]));
      }
      if (!box.isEmpty()) { const s = box.getSize(new THREE.Vector3()); R = 0.006 * Math.max(1e-6, Math.min(s.x || s.length(), s.y || s.length(), s.z || s.length())); }
    }
    DATA.stages.forEach(buildStage);
    const panel = document.getElementById("stages");
    for (const st of DATA.stages) panel.append(stagePanel(st));
    if (DATA.run.not_run && DATA.run.not_run.length) panel.append(el("p", { class: "meta" }, `not run: ${DATA.run.not_run.map((s) => s.name).join(", ")}`));
    const notes = document.getElementById("notes");
    for (const n of DATA.notes || []) notes.append(el("div", {}, "note: " + n));
    legend(DATA.stages);
    for (const ts of timeStages) select.append(el("option", { value: ts.name }, `${ts.name} (${ts.kind === "mesh" ? "tissue" : "motion"})`));
    if (timeStages.length) choose(timeStages.find((t) => t.kind === "timeline") ? timeStages.find((t) => t.kind === "timeline").name : timeStages[0].name);
    countDrawn();
    resize();
    frame("iso");
  }

  // ------------------------------------------------------------------ the live view
  // The static scene (obstacles, the recommended path, the ghost's path) is drawn by WebGL, again only when the
  // view changes; what moves with every sample (the trail, the instrument, and for a guide stage the trainee's
  // cues: the instrument coloured by clearance, the deviation arrow to the closest path point, the expert ghost,
  // the critical-region banner) is drawn on a 2D canvas over it, so a sample costs a few 2D strokes, not a 3D
  // frame: without a GPU (software WebGL) that is what keeps the cues within a frame of their sample.
  S.live = {
    messages: 0, tips: 0, updates: 0, updateTimes: [], tipTimes: [], connected: false, stage: null, status: null,
    last: null, events: [], closed: false, cue: null,
    // the frames drawn, the budget (frames a second, 0 none) and the WebGL renderer that chose it (FRAME_MS)
    frames: 0, fps: LIVE_FPS, renderer: RENDERER,
    // samples dropped on the way (never delayed): by the run's feed (its queue full) and by the viewer for this page
    // (this page not keeping up: its queue in the viewer is bounded, the oldest go first)
    drops: { feed: 0, page: 0 },
    // cue latency (ms): from each sample's arrival at the stage (its "wall" clock time) to the end of the first frame
    // drawn after the page got it; with #latency in the URL that frame is read back (getImageData), so it is in pixels
    // and (arrivalLatency) to the page's handling of its message, so the page's own share can be told apart
    pending: [], cueLatency: [], arrivalLatency: [], measurePixels: /latency/.test(location.hash),
  };
  const CUE_COLOURS = { clear: "#2ca02c", critical: "#f2b01e", below: "#d62728", contact: "#7f0000" };
  const ARROW = "#9467bd", TRAIL = "#1f6fb4", INSTRUMENT = "#ff7f0e";
  // a sample's clearance cue: contact, below d_thresh outside a critical region, in a critical region, clear
  function clearanceClass(p, threshold) {
    if (typeof p.clearance !== "number") return p.critical ? "critical" : "clear";
    if (p.clearance <= 0) return "contact";
    if (threshold && p.clearance < threshold && !p.critical) return "below";
    return p.critical ? "critical" : "clear";
  }

  function buildLive() {
    header(DATA.run);
    resize();
    frame("iso");
    const live = {
      name: "", guide: false, threshold: null, tolerance: null, positions: new Float32Array(3 * 4096), n: 0,
      projected: new Float32Array(2 * 4096), projectedN: 0, projectedFor: -1, reference: null, ghostPath: null,
      clearance: [], times: [], criticalSince: null,
    };
    // the materials a stage's start adds, compiled now (tiny stand-ins drawn once): compiling their shaders when
    // the stage starts would hold its first samples back by tens of milliseconds on software WebGL
    const referenceMaterial = new THREE.MeshLambertMaterial({ color: colour("#555555"), transparent: true, opacity: 0.5, depthWrite: false });
    const ghostPathMaterial = new THREE.LineBasicMaterial({ color: colour(GHOST), transparent: true, opacity: 0.55 });
    const warm = new THREE.Group();
    warm.add(new THREE.Mesh(tube(new Float32Array([0, 0, 0, 1e-9, 0, 0]), 1e-10, null, 8), referenceMaterial));
    warm.add(new THREE.Line(lineGeometry(new Float32Array([0, 0, 0, 1e-9, 0, 0])), ghostPathMaterial));
    world.add(warm);
    const overlay = document.getElementById("overlay"), octx = overlay.getContext("2d");
    const trail = document.getElementById("trail"), tctx = trail.getContext("2d");
    const banner = document.getElementById("cue-banner"), hud = document.getElementById("cue-hud");
    const info = el("div", { class: "message", id: "live-info" }, "waiting for a running stage…");
    const dropsInfo = el("div", { class: "message", id: "live-drops" }, "samples dropped: 0");
    document.getElementById("stages").append(el("details", { class: "stage", open: "" }, el("summary", {}, "live"), info, dropsInfo, el("div", { id: "live-events" })));
    timebar.style.display = "block";
    slider.style.display = "none";
    document.getElementById("play").style.display = "none";
    select.style.display = "none";
    const liveTs = { name: "live", kind: "timeline", count: 0, times: [], timeUnit: "s", series: [], events: [], set() { return {}; } };
    function onStage(p) {
      live.name = p.name;
      live.n = live.projectedN = 0;
      live.times = []; live.clearance = []; live.threshold = p.threshold || p.clearance_threshold || null;
      live.guide = p.kind === "guide"; live.tolerance = p.deviation_tolerance || null; live.criticalSince = null;
      liveTs.events = []; liveTs.series = [{ name: "clearance", unit: "m", values: live.clearance, colour: "#2ca02c", threshold: live.threshold }];
      for (const key of ["reference", "ghostPath"]) if (live[key]) { world.remove(live[key]); live[key] = null; }
      if (p.recommended && p.recommended.length > 1) {
        const g = tube(new Float32Array(p.recommended.flat()), 0.8 * R, null, 8);
        live.reference = new THREE.Mesh(g, referenceMaterial);
        live.reference.userData = { kind: "reference", label: `${p.kind === "guide" ? "recommended" : "planned"} path${p.path_from ? " (" + p.path_from + ")" : ""}` };
        pickable.push(live.reference);
        world.add(live.reference);
      }
      if (p.ghost_path && p.ghost_path.length > 1) {
        live.ghostPath = new THREE.Line(lineGeometry(new Float32Array(p.ghost_path.flat())), ghostPathMaterial);
        live.ghostPath.userData = { kind: "ghost-path", label: `expert ghost's path (${ghostLabel(p.ghost || {})})` };
        world.add(live.ghostPath);
      }
      banner.style.display = hud.style.display = "none";
      written.clear();
      S.live.stage = p;
      S.live.cue = cueWaiting = null;
      info.textContent = `${p.kind || "stage"} ${p.name} (${p.plugin || ""}) running`;
      active = liveTs;
      requestRender();
    }
    // the cues' DOM (banner, numbers): built once, its text and colours written at most once a frame and only
    // when they change (a style and layout pass per sample would hold the page's messages back)
    const hudText = [document.createTextNode(""), document.createTextNode(""), document.createTextNode("expert ghost")];
    const hudSwatch = [el("span", { class: "sw" }), el("span", { class: "sw", style: `background:${ARROW}` }), el("span", { class: "sw", style: `background:${GHOST}` })];
    const hudGhost = el("span", {}, el("br"), hudSwatch[2], hudText[2]);
    hud.append(hudSwatch[0], hudText[0], el("br"), hudSwatch[1], hudText[1], hudGhost);
    let cueWaiting = null;
    const written = new Map(); // what was last written where (a style reads back normalised: compare with this)
    function assign(node, key, value) {
      let was = written.get(node);
      if (!was) written.set(node, (was = {}));
      if (was[key] !== value) { node[key] = value; was[key] = value; }
    }
    function paintCues() {
      const c = cueWaiting;
      if (!c) return;
      cueWaiting = null;
      assign(banner, "textContent", c.banner);
      assign(banner, "className", `cue-${c.style}`);
      assign(banner.style, "display", c.banner ? "block" : "none");
      assign(hud.style, "display", "block");
      assign(hudSwatch[0].style, "background", c.colour);
      assign(hudText[0], "data", c.clearanceText);
      assign(hudText[1], "data", c.deviationText);
      assign(hudGhost.style, "display", c.ghost ? "inline" : "none");
    }
    function cues(p) {
      const kind = clearanceClass(p, live.threshold);
      if (p.critical && live.criticalSince === null) live.criticalSince = p.t;
      if (!p.critical) live.criticalSince = null;
      let text = "", style = kind;
      if (kind === "contact") text = "CONTACT: the instrument touches an obstacle";
      else if (kind === "below") text = `too close: clearance ${len(p.clearance, 3)} below d_thresh ${len(live.threshold, 3)}`;
      else if (p.critical) {
        text = p.t - live.criticalSince < 1.5
          ? "entering a critical region: no detour keeps d_thresh here; follow the path"
          : "in a critical region: follow the path";
      } else if (live.tolerance && p.deviation > live.tolerance) {
        text = `off the path by ${len(p.deviation, 3)} (tolerance ${len(live.tolerance, 3)}): follow the arrow`;
        style = "deviation";
      }
      S.live.cue = { clearance: kind, colour: CUE_COLOURS[kind], banner: text, closest: p.closest || null, ghost: p.ghost || null };
      cueWaiting = {
        ...S.live.cue, style, clearanceText: `clearance ${len(p.clearance, 3)}`, deviationText: `deviation ${len(p.deviation, 3)}`,
      };
    }
    function onTip(p) {
      if (3 * (live.n + 1) > live.positions.length) {
        const bigger = new Float32Array(live.positions.length * 2);
        bigger.set(live.positions);
        live.positions = bigger;
        const projected = new Float32Array(live.projected.length * 2);
        projected.set(live.projected);
        live.projected = projected;
      }
      live.positions.set(p.tip, 3 * live.n);
      live.n++;
      live.times.push(p.t);
      live.clearance.push(p.clearance === undefined ? NaN : p.clearance);
      liveTs.times = live.times; liveTs.count = live.times.length;
      S.live.tips++;
      S.live.tipTimes.push(performance.now());
      if (S.live.tipTimes.length > 4000) S.live.tipTimes.splice(0, 2000);
      S.live.last = p;
      if (live.guide) cues(p);
      if (typeof p.wall === "number" && S.live.pending.length < 20000) {
        S.live.pending.push(p.wall);
        S.live.arrivalLatency.push(performance.timeOrigin + performance.now() - 1000 * p.wall);
        if (S.live.arrivalLatency.length > 200000) S.live.arrivalLatency.splice(0, 100000);
      }
      state = { stage: live.name, index: liveTs.count - 1, t: p.t, tip: p.tip, clearance: p.clearance, deviation: p.deviation };
      liveDirty = true;
      overlayDirty = true;
    }
    // the moving parts, on the 2D canvas over the 3D view (device pixels)
    const v = new THREE.Vector3();
    function project(p) {
      v.set(p[0], p[1], p[2]).project(camera);
      return v.z < 1 ? [((v.x + 1) / 2) * overlay.width, ((1 - v.y) / 2) * overlay.height] : null;
    }
    function disk(at, radius, fill, alpha) {
      if (!at) return;
      octx.globalAlpha = alpha;
      octx.beginPath();
      octx.arc(at[0], at[1], radius, 0, 2 * Math.PI);
      octx.fillStyle = fill;
      octx.fill();
      octx.globalAlpha = 1;
      octx.lineWidth = Math.max(1, radius / 5);
      octx.strokeStyle = "#ffffff";
      octx.stroke();
    }
    function arrow(a, b, width) {
      if (!a || !b) return;
      const dx = b[0] - a[0], dy = b[1] - a[1], length = Math.hypot(dx, dy);
      if (length < 2) return;
      const head = Math.min(4 * width, 0.6 * length), ux = dx / length, uy = dy / length;
      octx.strokeStyle = octx.fillStyle = ARROW;
      octx.lineWidth = width;
      octx.lineCap = "round";
      octx.beginPath();
      octx.moveTo(a[0], a[1]);
      octx.lineTo(b[0] - head * ux, b[1] - head * uy);
      octx.stroke();
      octx.beginPath();
      octx.moveTo(b[0], b[1]);
      octx.lineTo(b[0] - head * ux - 0.6 * head * uy, b[1] - head * uy + 0.6 * head * ux);
      octx.lineTo(b[0] - head * ux + 0.6 * head * uy, b[1] - head * uy - 0.6 * head * ux);
      octx.closePath();
      octx.fill();
    }
    drawOverlay = function () {
      paintCues();
      octx.clearRect(0, 0, overlay.width, overlay.height);
      const p = S.live.last;
      if (!live.n || !p) return null;
      const dpr = window.devicePixelRatio || 1;
      // the trail: only its new segments, unless the view changed (then all of it, reprojected)
      let from = Math.max(0, live.projectedN - 1);
      if (live.projectedFor !== viewVersion || trail.width !== overlay.width || trail.height !== overlay.height) {
        trail.width = overlay.width; trail.height = overlay.height;
        tctx.clearRect(0, 0, trail.width, trail.height);
        live.projectedFor = viewVersion;
        live.projectedN = from = 0;
      }
      for (let i = live.projectedN; i < live.n; i++) {
        const q = project([live.positions[3 * i], live.positions[3 * i + 1], live.positions[3 * i + 2]]);
        live.projected[2 * i] = q ? q[0] : NaN; live.projected[2 * i + 1] = q ? q[1] : NaN;
      }
      live.projectedN = live.n;
      tctx.strokeStyle = TRAIL;
      tctx.lineWidth = 1.5 * dpr;
      tctx.lineJoin = tctx.lineCap = "round";
      tctx.beginPath();
      let open = false;
      for (let i = from; i < live.n; i++) {
        const x = live.projected[2 * i], y = live.projected[2 * i + 1];
        if (!isFinite(x)) { open = false; continue; }
        if (open) tctx.lineTo(x, y); else { tctx.moveTo(x, y); open = true; }
      }
      tctx.stroke();
      // the cues: the ghost, the instrument coloured by clearance, and on top the arrow to the closest path point
      const tip = project(p.tip);
      if (p.ghost) disk(project(p.ghost), 7 * dpr, GHOST, 0.85);
      disk(tip, 6.5 * dpr, live.guide ? CUE_COLOURS[clearanceClass(p, live.threshold)] : INSTRUMENT, 1);
      if (live.guide && p.closest) arrow(tip, project(p.closest), 3 * dpr);
      return tip;
    };
    let labelPending = false;
    drawText = () => labelPending && (refreshLabel(), true);
    function refreshLabel() {
      labelPending = false;
      const p = S.live.last;
      if (!p) return;
      let text = `t = ${(+p.t).toFixed(3)} s`;
      if (p.clearance !== undefined) text += ` · clearance ${len(p.clearance, 3)}`;
      if (p.deviation !== undefined) text += ` · deviation ${len(p.deviation, 3)}`;
      text += ` · ${S.live.tips} samples`;
      label.textContent = text;
      const now = performance.now();
      if (now - chartAt > 200) { chartAt = now; drawChart(); } // the history, not a cue: 5 times a second is enough
      else if (!chartPending) { chartPending = true; setTimeout(() => { chartPending = false; chartAt = performance.now(); drawChart(); }, 200); }
    }
    let chartAt = 0, chartPending = false;
    function handle(msg) {
      S.live.messages++;
      const p = msg.payload || {};
      switch (msg.channel) {
        case "scene":
          buildScene(p);
          frame("iso");
          countDrawn();
          break;
        case "run":
          unit = p.length_unit || unit; unitScale = p.unit_scale || unitScale;
          header(Object.assign({}, p, { status: "running" }));
          break;
        case "stage": onStage(p); break;
        case "tip": onTip(p); break;
        case "event":
          S.live.events.push(p);
          liveTs.events.push(p);
          document.getElementById("live-events").prepend(el("div", {}, `${p.t !== undefined ? (+p.t).toFixed(3) + " s " : ""}`, el("b", {}, p.kind || "event"), p.message ? `: ${p.message}` : ""));
          break;
        case "status":
          S.live.status = p;
          info.textContent = `${live.name}: ${p.status}${p.message ? ": " + p.message : ""}`;
          break;
        case "run_end":
          header(Object.assign({}, DATA.run, p));
          break;
        case "drops": {
          const d = S.live.drops;
          if (typeof p.feed === "number") d.feed = p.feed;
          if (typeof p.page === "number") d.page = p.page;
          dropsInfo.textContent = `samples dropped: ${d.feed + d.page}` + (d.feed + d.page ? ` (by the run's feed ${d.feed}, by the viewer for this page ${d.page})` : "");
          dropsInfo.style.color = d.feed + d.page ? "#b35900" : "";
          break;
        }
      }
      labelPending = true; // redrawn in the next frame the budget allows (loop)
    }
    let attempts = 0;
    function connect() {
      const ws = new WebSocket(`ws://${location.host}/watch`);
      ws.onopen = () => { S.live.connected = true; attempts = 0; };
      ws.onmessage = (ev) => {
        const msg = JSON.parse(ev.data);
        if (Array.isArray(msg)) msg.forEach(handle); else handle(msg);
      };
      ws.onclose = () => {
        S.live.connected = false;
        if (++attempts <= 30) setTimeout(connect, 1000); // the viewer restarted: try again, for half a minute
        else S.live.closed = true;
      };
    }
    connect();
    countDrawn();
  }

  try {
    if (LIVE) buildLive(); else buildReport();
  } catch (e) {
    S.errors.push(String(e && e.stack ? e.stack : e));
    console.error(e);
  }
  requestAnimationFrame(loop);
})();

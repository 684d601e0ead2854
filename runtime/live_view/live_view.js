// mocapd's live view: a three.js scene per subject (raw markers, cleaned markers coloured
// by status and repairing detector, the solved skeleton, the retargeted character) fed by
// the daemon's WebSocket /live, and panels for frame, timecode, latency and repairs.
// window.mocapdView exposes what a test needs (frames received, render rate, where the
// skeleton's joints are drawn on screen).
(function () {
  "use strict";
  const SKELETON_COLOR = 0xffcc00;  // the test looks for this colour at the joints
  const CHARACTER_COLOR = 0x33ddff;
  const RAW_COLOR = 0x8a8f99;
  const OBSERVED_COLOR = 0xf4f4f4;
  const UNRECOVERABLE_COLOR = 0xff3030;
  // Repaired samples by the detector that repaired them (the wire's reason codes 1..10).
  const REASONS = ["none", "missing", "disagreement", "residual", "spike", "rigid distance",
                   "swap", "frozen", "fallen off", "small track", "trimmed"];
  const REASON_COLORS = [0xf4f4f4, 0x4da3ff, 0xb36bff, 0xff8c3a, 0xff4fa3, 0x3ad6a0,
                         0xffe14d, 0x7ad03a, 0xc0a080, 0x5fd0d0, 0xa0a0ff];
  const HIDDEN = -1e4;  // where a point without a position is parked (beyond the far plane)

  const view = {
    framesReceived: 0, messagesReceived: 0, renderFps: 0, firstFrameMs: null,
    connected: false, subjects: {},
    skeletonColor: [(SKELETON_COLOR >> 16) & 255, (SKELETON_COLOR >> 8) & 255, SKELETON_COLOR & 255],
    projectedJoints: projectedJoints,
  };
  window.mocapdView = view;

  const container = document.getElementById("view");
  const renderer = new THREE.WebGLRenderer({antialias: true, preserveDrawingBuffer: true});
  renderer.setPixelRatio(window.devicePixelRatio || 1);
  renderer.setSize(window.innerWidth, window.innerHeight);
  renderer.setClearColor(0x15171c);
  container.appendChild(renderer.domElement);
  const scene = new THREE.Scene();
  const camera = new THREE.PerspectiveCamera(45, window.innerWidth / window.innerHeight, 0.05, 200);
  camera.position.set(4, 3, 6);
  const controls = new THREE.OrbitControls(camera, renderer.domElement);
  controls.target.set(0, 1, 0);
  controls.update();
  let grid = null;
  let upAxis = null;  // decided from the first skeleton: the axis it is tallest along

  window.addEventListener("resize", () => {
    camera.aspect = window.innerWidth / window.innerHeight;
    camera.updateProjectionMatrix();
    renderer.setSize(window.innerWidth, window.innerHeight);
  });

  const subjectSelect = document.getElementById("subject");
  const pauseBox = document.getElementById("pause");
  const rawBox = document.getElementById("raw");
  const followBox = document.getElementById("follow");
  const stateText = document.getElementById("state");
  const frameText = document.getElementById("frame");
  const counterTable = document.getElementById("counters");
  const spark = document.getElementById("spark").getContext("2d");
  const latency = {};  // subject -> [[p50, p99], ...] (last 120 stats ticks)
  let focusPending = true;

  document.getElementById("legend").innerHTML =
      [["skeleton", SKELETON_COLOR], ["character", CHARACTER_COLOR], ["raw", RAW_COLOR],
       ["observed", OBSERVED_COLOR], ["unrecoverable", UNRECOVERABLE_COLOR]]
          .concat(REASONS.slice(1).map((r, i) => ["repaired: " + r, REASON_COLORS[i + 1]]))
          .map(([name, c]) => `<span><i style="background:#${c.toString(16).padStart(6, "0")}"></i>${name}</span>`)
          .join("");

  function pointCloud(count, color, size) {
    const geometry = new THREE.BufferGeometry();
    geometry.setAttribute("position", new THREE.BufferAttribute(new Float32Array(count * 3).fill(HIDDEN), 3));
    geometry.setAttribute("color", new THREE.BufferAttribute(new Float32Array(count * 3).fill(1), 3));
    const material = new THREE.PointsMaterial({size: size, sizeAttenuation: false,
                                               vertexColors: color === null ? THREE.VertexColors : THREE.NoColors,
                                               color: color === null ? 0xffffff : color});
    const points = new THREE.Points(geometry, material);
    points.frustumCulled = false;
    return points;
  }

  function bones(parents, color) {
    const pairs = parents.map((p, j) => [p, j]).filter(([p]) => p >= 0);
    const geometry = new THREE.BufferGeometry();
    geometry.setAttribute("position", new THREE.BufferAttribute(new Float32Array(pairs.length * 6).fill(HIDDEN), 3));
    const lines = new THREE.LineSegments(geometry, new THREE.LineBasicMaterial({color: color, linewidth: 2}));
    lines.frustumCulled = false;
    lines.userData.pairs = pairs;
    const joints = pointCloud(parents.length, color, 7);
    const group = new THREE.Group();
    group.add(lines, joints);
    group.userData = {lines: lines, joints: joints};
    return group;
  }

  function dispose(object) {
    object.traverse((o) => {
      if (o.geometry) o.geometry.dispose();
      if (o.material) o.material.dispose();
    });
  }

  function escapeHtml(text) {
    return String(text).replace(/[&<>"]/g, (c) => ({"&": "&amp;", "<": "&lt;", ">": "&gt;", '"': "&quot;"})[c]);
  }

  function describe(subjects) {
    for (const name of Object.keys(view.subjects)) {
      scene.remove(view.subjects[name].group);
      dispose(view.subjects[name].group);
      delete view.subjects[name];
    }
    const chosen = subjectSelect.value || onlySubject;
    subjectSelect.innerHTML = '<option value="">all subjects</option>';
    // By name, numbers in order (actor2 before actor10), whichever worker each runs on.
    const byName = subjects.slice().sort((a, b) => a.name.localeCompare(b.name, undefined, {numeric: true}));
    for (const d of byName) {
      const s = {
        description: d, generation: d.generation, group: new THREE.Group(),
        raw: pointCloud(d.markers.length, RAW_COLOR, 4),
        markers: pointCloud(d.markers.length, null, 6),
        skeleton: bones(d.parents, SKELETON_COLOR),
        character: d.character_parents.length ? bones(d.character_parents, CHARACTER_COLOR) : null,
        joints: null, frame: null,
      };
      s.group.add(s.raw, s.markers, s.skeleton);
      if (s.character) s.group.add(s.character);
      scene.add(s.group);
      view.subjects[d.name] = s;
      const option = document.createElement("option");
      option.value = option.textContent = d.name;
      subjectSelect.appendChild(option);
    }
    if (chosen && view.subjects[chosen]) subjectSelect.value = chosen;
    focusPending = true;
  }

  function setPoints(points, flat) {
    const position = points.geometry.attributes.position;
    for (let i = 0; i < position.count * 3; ++i) {
      const v = flat[i];
      position.array[i] = v === null || v === undefined ? HIDDEN : v;
    }
    position.needsUpdate = true;
  }

  function setBones(group, flat) {
    setPoints(group.userData.joints, flat);
    const lines = group.userData.lines;
    const position = lines.geometry.attributes.position;
    lines.userData.pairs.forEach(([a, b], k) => {
      // A bone to a joint without a position is not drawn (not drawn to the origin).
      const known = [0, 1, 2].every((i) => flat[a * 3 + i] !== null && flat[b * 3 + i] !== null);
      for (let i = 0; i < 3; ++i) {
        position.array[k * 6 + i] = known ? flat[a * 3 + i] : HIDDEN;
        position.array[k * 6 + 3 + i] = known ? flat[b * 3 + i] : HIDDEN;
      }
    });
    position.needsUpdate = true;
  }

  function colorOf(status, reason) {
    if (status === 2) return UNRECOVERABLE_COLOR;
    if (status === 1) return REASON_COLORS[reason] || REASON_COLORS[1];
    return OBSERVED_COLOR;
  }

  function chooseUp(joints) {
    let best = 1, extent = -1;
    for (let axis = 0; axis < 3; ++axis) {
      let lo = Infinity, hi = -Infinity;
      for (let j = axis; j < joints.length; j += 3) {
        if (joints[j] === null) continue;
        lo = Math.min(lo, joints[j]);
        hi = Math.max(hi, joints[j]);
      }
      if (hi - lo > extent) { extent = hi - lo; best = axis; }
    }
    upAxis = best;
    camera.up.set(best === 0 ? 1 : 0, best === 1 ? 1 : 0, best === 2 ? 1 : 0);
    grid = new THREE.GridHelper(20, 40, 0x4a505c, 0x30353f);
    if (best === 2) grid.rotation.x = Math.PI / 2;
    if (best === 0) grid.rotation.z = Math.PI / 2;
    scene.add(grid);
  }

  function shownNames() {
    return subjectSelect.value ? [subjectSelect.value] : Object.keys(view.subjects);
  }

  // The centre of the shown subjects' roots, or null before their first frame.
  function centreOfShown() {
    const centre = new THREE.Vector3();
    let n = 0;
    for (const name of shownNames()) {
      const s = view.subjects[name];
      if (!s || !s.joints || s.joints[0] === null) continue;
      centre.add(new THREE.Vector3(s.joints[0], s.joints[1], s.joints[2]));
      ++n;
    }
    return n === 0 ? null : {centre: centre.divideScalar(n), count: n};
  }

  function focus() {
    const shown = centreOfShown();
    if (shown === null) return false;
    const offset = camera.position.clone().sub(controls.target);
    controls.target.copy(shown.centre);
    camera.position.copy(shown.centre).add(offset.setLength(Math.max(4, 2.5 * shown.count)));
    controls.update();
    moveGrid();
    return true;
  }

  // Actors walk across a volume (and a synthetic take walks on for ever): the camera keeps
  // its angle and distance (which the mouse sets) and moves with them.
  function follow() {
    const shown = centreOfShown();
    if (shown === null) return;
    const delta = shown.centre.sub(controls.target);
    controls.target.add(delta);
    camera.position.add(delta);
    moveGrid();
  }

  // The floor grid goes with the camera, by whole cells so that it looks fixed underfoot.
  function moveGrid() {
    if (grid === null) return;
    const cell = 0.5;
    for (let axis = 0; axis < 3; ++axis)
      if (axis !== upAxis) grid.position.setComponent(axis, Math.round(controls.target.getComponent(axis) / cell) * cell);
  }

  // The wire carries whole millimetres (exact and short); the scene is in metres.
  function metres(flat) {
    return flat.map((v) => (v === null ? null : v / 1000));
  }

  function onFrame(message) {
    ++view.framesReceived;
    if (pauseBox.checked) return;
    for (const f of message.subjects) {
      const s = view.subjects[f.name];
      if (!s || s.generation !== f.generation) continue;
      const joints = metres(f.joints);
      setPoints(s.raw, metres(f.raw));
      setPoints(s.markers, metres(f.markers));
      const colors = s.markers.geometry.attributes.color;
      const c = new THREE.Color();
      for (let m = 0; m < f.status.length; ++m) {
        c.setHex(colorOf(f.status[m], f.reason[m]));
        colors.setXYZ(m, c.r, c.g, c.b);
      }
      colors.needsUpdate = true;
      setBones(s.skeleton, joints);
      if (s.character && f.character) setBones(s.character, metres(f.character));
      s.joints = joints;
      s.frame = f;
      if (upAxis === null) chooseUp(joints);
    }
    if (focusPending && focus()) focusPending = false;
    else if (followBox.checked) follow();
    frameText.textContent = shownNames().map((name) => {
      const f = view.subjects[name] && view.subjects[name].frame;
      return f ? `${name}: frame ${f.frame}${f.timecode ? " · " + f.timecode : ""} · ${f.state} · residual ${f.residual_mm.toFixed(1)} mm`
               : `${name}: no frame yet`;
    }).join("\n");
    frameText.style.whiteSpace = "pre";
  }

  function onStats(message) {
    const rows = ["<tr><th>subject</th><th>state</th><th>published</th><th>repaired</th><th>unrecoverable</th><th>stalls</th><th>restarts</th><th>calibration</th></tr>"];
    for (const s of message.subjects) {
      (latency[s.name] = latency[s.name] || []).push([s.latency_p50_ms, s.latency_p99_ms]);
      if (latency[s.name].length > 120) latency[s.name].shift();
      rows.push(`<tr><td>${escapeHtml(s.name)}</td><td>${s.state}${s.model_suspect ? " (model?)" : ""}</td><td>${s.frames_published}</td>` +
                `<td>${s.samples_repaired}</td><td>${s.samples_unrecoverable}</td><td>${s.stalls}</td><td>${s.restarts}</td>` +
                `<td>${calibrationText(s.calibration)}</td></tr>`);
    }
    counterTable.innerHTML = rows.join("");
    drawSpark();
  }

  // A live calibration's progress: its state, joints ready, and those still waiting for
  // the motion to show them.
  function calibrationText(c) {
    if (!c) return "–";
    let text = `${c.state} ${c.collected_s.toFixed(0)} s, ${c.joints_ready}/${c.joints} joints ready`;
    if (c.waiting_for.length) text += ` (waiting: ${c.waiting_for.slice(0, 4).join(", ")}${c.waiting_for.length > 4 ? ", …" : ""})`;
    return escapeHtml(text);
  }

  function drawSpark() {
    const name = subjectSelect.value || Object.keys(latency)[0];
    const points = latency[name] || [];
    const w = spark.canvas.width, h = spark.canvas.height;
    spark.clearRect(0, 0, w, h);
    const top = Math.max(1, ...points.map((p) => p[1] || 0)) * 1.2;
    [[0, "#3ad6a0"], [1, "#ff8c3a"]].forEach(([k, color]) => {
      spark.strokeStyle = color;
      spark.beginPath();
      points.forEach((p, i) => {
        const x = (i / 119) * w, y = h - ((p[k] || 0) / top) * h;
        if (i === 0) spark.moveTo(x, y); else spark.lineTo(x, y);
      });
      spark.stroke();
    });
    const last = points[points.length - 1];
    document.getElementById("sparklabel").textContent =
        `${name || ""} processing latency p50 / p99: ${last && last[0] !== null ? last[0].toFixed(2) : "–"} / ` +
        `${last && last[1] !== null ? last[1].toFixed(2) : "–"} ms (scale ${top.toFixed(1)} ms)`;
  }

  function projectedJoints(name) {
    const s = view.subjects[name || Object.keys(view.subjects)[0]];
    if (!s || !s.joints) return [];
    const out = [];
    const rect = renderer.domElement.getBoundingClientRect();
    for (let j = 0; j < s.joints.length; j += 3) {
      const p = new THREE.Vector3(s.joints[j], s.joints[j + 1], s.joints[j + 2]).project(camera);
      if (p.z < -1 || p.z > 1) continue;
      out.push([rect.left + (p.x + 1) / 2 * rect.width, rect.top + (1 - p.y) / 2 * rect.height]);
    }
    return out;
  }

  // /?subject=NAME shows that subject alone (its frames only, over /live?subject=NAME).
  const onlySubject = new URLSearchParams(location.search).get("subject") || "";

  function connect() {
    const url = (location.protocol === "https:" ? "wss://" : "ws://") + location.host + "/live" +
                (onlySubject ? "?subject=" + encodeURIComponent(onlySubject) : "");
    const socket = new WebSocket(url);
    socket.onopen = () => { view.connected = true; stateText.textContent = "live"; stateText.className = ""; };
    socket.onclose = () => {
      view.connected = false;
      stateText.textContent = "disconnected: retrying";
      stateText.className = "bad";
      setTimeout(connect, 1000);
    };
    socket.onmessage = (event) => {
      ++view.messagesReceived;
      const message = JSON.parse(event.data);
      if (message.type === "subjects") describe(message.subjects);
      else if (message.type === "frame") onFrame(message);
      else if (message.type === "stats") onStats(message);
    };
  }

  subjectSelect.addEventListener("change", () => { focus(); drawSpark(); });
  rawBox.addEventListener("change", () => {
    for (const s of Object.values(view.subjects)) s.raw.visible = rawBox.checked;
  });

  let rendered = 0, since = performance.now();
  function animate() {
    requestAnimationFrame(animate);
    controls.update();
    renderer.render(scene, camera);
    ++rendered;
    if (view.firstFrameMs === null && view.framesReceived > 0) view.firstFrameMs = performance.now();
    const now = performance.now();
    if (now - since >= 1000) {
      view.renderFps = rendered * 1000 / (now - since);
      rendered = 0;
      since = now;
    }
  }
  // A subject this daemon does not solve would have its socket refused (404) again and
  // again: say so once, with the names it does solve, and do not connect.
  function start() {
    if (!onlySubject) return connect();
    fetch("subjects").then((r) => r.json()).then((subjects) => {
      const names = subjects.map((s) => s.name);
      if (names.includes(onlySubject)) return connect();
      stateText.textContent = `unknown subject "${onlySubject}"; this daemon solves: ${names.join(", ") || "none"}`;
      stateText.className = "bad";
    }).catch(() => connect());
  }
  start();
  animate();
})();

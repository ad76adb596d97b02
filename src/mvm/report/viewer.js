/* mvm report: a small canvas-2D 3D viewer (orbit: drag; pan: shift/right drag; zoom: wheel;
   reset: double click). Reads the JSON of <script id="mvm-data"> and reports its state in
   #mvm-status (data-state="rendered" once drawn, "error" after any error). */
(function () {
  "use strict";
  var data = JSON.parse(document.getElementById("mvm-data").textContent);
  var view = data.view;
  var canvas = document.getElementById("mvm-view");
  var ctx = canvas.getContext("2d");
  var status = document.getElementById("mvm-status");
  var show = {points: true, cameras: true, truth: !!view.truth, labels: true, floor: true};
  var home = {yaw: view.heading, pitch: 0.5, dist: 2.0 * view.radius, target: [0, 0, view.center_z]};
  var cam = {yaw: home.yaw, pitch: home.pitch, dist: home.dist, target: home.target.slice()};
  var FOV = 45 * Math.PI / 180;

  function sub(a, b) { return [a[0] - b[0], a[1] - b[1], a[2] - b[2]]; }
  function dot(a, b) { return a[0] * b[0] + a[1] * b[1] + a[2] * b[2]; }
  function cross(a, b) { return [a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0]]; }
  function unit(a) { var n = Math.sqrt(dot(a, a)) || 1; return [a[0] / n, a[1] / n, a[2] / n]; }

  function basis() {
    var cp = Math.cos(cam.pitch);
    var dir = [cp * Math.cos(cam.yaw), cp * Math.sin(cam.yaw), Math.sin(cam.pitch)];
    var eye = [cam.target[0] + cam.dist * dir[0], cam.target[1] + cam.dist * dir[1], cam.target[2] + cam.dist * dir[2]];
    var forward = unit(sub(cam.target, eye));
    var right = unit(cross(forward, [0, 0, 1]));
    var up = cross(right, forward);
    return {eye: eye, forward: forward, right: right, up: up};
  }

  function projector(b, w, h) {
    var f = 0.5 * h / Math.tan(FOV / 2), near = 1e-3 * view.radius;
    return function (p) {
      if (!p) { return null; }
      var d = sub(p, b.eye), z = dot(d, b.forward);
      if (z < near) { return null; }
      return [w / 2 + f * dot(d, b.right) / z, h / 2 - f * dot(d, b.up) / z, z];
    };
  }

  function segment(proj, a, b) {
    var pa = proj(a), pb = proj(b);
    return pa && pb ? [pa, pb] : null;
  }

  function resize() {
    var ratio = window.devicePixelRatio || 1;
    var w = Math.max(1, Math.round(canvas.clientWidth * ratio)), h = Math.max(1, Math.round(canvas.clientHeight * ratio));
    if (canvas.width !== w || canvas.height !== h) { canvas.width = w; canvas.height = h; }
    return ratio;
  }

  function draw() {
    var ratio = resize(), w = canvas.width, h = canvas.height;
    var b = basis(), proj = projector(b, w, h), drawn = 0, i, j, s;
    ctx.setTransform(1, 0, 0, 1, 0, 0);
    ctx.fillStyle = "#fbfbfb";
    ctx.fillRect(0, 0, w, h);
    ctx.lineCap = "round";
    if (show.floor) {
      ctx.strokeStyle = "#e2e2e2"; ctx.lineWidth = ratio;
      var g = view.grid, n = Math.round(g.half / g.step);
      ctx.beginPath();
      for (i = -n; i <= n; i++) {
        var lines = [[[i * g.step, -g.half, g.z], [i * g.step, g.half, g.z]], [[-g.half, i * g.step, g.z], [g.half, i * g.step, g.z]]];
        for (j = 0; j < 2; j++) {
          s = segment(proj, lines[j][0], lines[j][1]);
          if (s) { ctx.moveTo(s[0][0], s[0][1]); ctx.lineTo(s[1][0], s[1][1]); }
        }
      }
      ctx.stroke();
    }
    if (show.points && view.points.length) {
      ctx.fillStyle = "rgba(90,90,90,0.55)";
      var r = 1.5 * ratio;
      for (i = 0; i + 2 < view.points.length; i += 3) {
        var q = proj([view.points[i], view.points[i + 1], view.points[i + 2]]);
        if (q) { ctx.fillRect(q[0] - r / 2, q[1] - r / 2, r, r); drawn++; }
      }
    }
    if (show.cameras && (view.path.length || view.frustums.length)) {
      ctx.strokeStyle = "#3a3a3a"; ctx.lineWidth = 1.5 * ratio;
      ctx.beginPath();
      var started = false;
      for (i = 0; i < view.path.length; i++) {
        var c = proj(view.path[i]);
        if (!c) { started = false; continue; }
        if (started) { ctx.lineTo(c[0], c[1]); } else { ctx.moveTo(c[0], c[1]); started = true; }
        drawn++;
      }
      ctx.stroke();
      ctx.strokeStyle = "rgba(40,90,160,0.8)"; ctx.lineWidth = ratio;
      ctx.beginPath();
      view.frustums.forEach(function (fr) {
        var edges = [[0, 1], [0, 2], [0, 3], [0, 4], [1, 2], [2, 3], [3, 4], [4, 1]];
        edges.forEach(function (e) {
          var sg = segment(proj, fr[e[0]], fr[e[1]]);
          if (sg) { ctx.moveTo(sg[0][0], sg[0][1]); ctx.lineTo(sg[1][0], sg[1][1]); drawn++; }
        });
      });
      ctx.stroke();
      if (show.labels && view.camera_labels) {
        ctx.font = (11 * ratio) + "px sans-serif"; ctx.fillStyle = "#28508f"; ctx.textAlign = "center";
        view.camera_labels.forEach(function (c) {
          var t = proj(c.at);
          if (t) { ctx.fillText(c.name, t[0], t[1] - 6 * ratio); }
        });
      }
    }
    var segments = [];
    function collect(skeletons, style) {
      skeletons.forEach(function (person) {
        view.skeleton.forEach(function (e) {
          var sg = segment(proj, person.joints[e[0]], person.joints[e[1]]);
          if (sg) { segments.push({s: sg, z: sg[0][2] + sg[1][2], color: person.color, style: style}); }
        });
      });
    }
    if (show.truth && view.truth) { collect(view.truth, "truth"); }
    collect(view.persons, "estimate");
    segments.sort(function (a, c) { return c.z - a.z; });
    var focal = 0.5 * h / Math.tan(FOV / 2);
    segments.forEach(function (sg) {
      var depth = 0.5 * (sg.s[0][2] + sg.s[1][2]);
      var width = (sg.style === "truth" ? 0.008 : 0.02) * view.person_scale * focal / depth;
      ctx.setLineDash(sg.style === "truth" ? [4 * ratio, 4 * ratio] : []);
      ctx.strokeStyle = sg.style === "truth" ? "#222" : sg.color;
      ctx.lineWidth = Math.max(1.5 * ratio, Math.min(10 * ratio, width));
      ctx.beginPath(); ctx.moveTo(sg.s[0][0], sg.s[0][1]); ctx.lineTo(sg.s[1][0], sg.s[1][1]); ctx.stroke();
      drawn++;
    });
    ctx.setLineDash([]);
    view.persons.forEach(function (person) {
      ctx.fillStyle = person.color;
      person.joints.forEach(function (p, j) {
        var q = proj(p), flag = person.flags ? person.flags.charAt(j) : "1";
        if (!q) { return; }
        ctx.beginPath(); ctx.arc(q[0], q[1], (flag === "1" ? 2.5 : 3) * ratio, 0, 2 * Math.PI);
        if (flag === "1") { ctx.fill(); } else {
          ctx.fillStyle = flag === "3" ? "#9a9a9a" : "#ffffff"; ctx.fill();
          ctx.strokeStyle = person.color; ctx.lineWidth = ratio; ctx.stroke(); ctx.fillStyle = person.color;
        }
      });
      if (show.labels && person.head) {
        var t = proj(person.head);
        if (t) {
          ctx.font = (12 * ratio) + "px sans-serif"; ctx.fillStyle = "#111"; ctx.textAlign = "center";
          ctx.fillText(String(person.id), t[0], t[1] - 8 * ratio);
        }
      }
    });
    return drawn;
  }

  function redraw() {
    window.requestAnimationFrame(function () { status.setAttribute("data-segments", String(draw())); });
  }

  var drag = null;
  canvas.addEventListener("contextmenu", function (e) { e.preventDefault(); });
  canvas.addEventListener("pointerdown", function (e) {
    drag = {x: e.clientX, y: e.clientY, pan: e.shiftKey || e.button === 2};
    canvas.setPointerCapture(e.pointerId);
  });
  canvas.addEventListener("pointerup", function () { drag = null; });
  canvas.addEventListener("pointermove", function (e) {
    if (!drag) { return; }
    var dx = e.clientX - drag.x, dy = e.clientY - drag.y;
    drag.x = e.clientX; drag.y = e.clientY;
    if (drag.pan) {
      var b = basis(), k = cam.dist / canvas.clientHeight;
      for (var i = 0; i < 3; i++) { cam.target[i] += k * (-dx * b.right[i] + dy * b.up[i]); }
    } else {
      cam.yaw -= dx * 0.01;
      cam.pitch = Math.max(-1.5, Math.min(1.5, cam.pitch + dy * 0.01));
    }
    redraw();
  });
  canvas.addEventListener("wheel", function (e) {
    e.preventDefault();
    cam.dist = Math.max(0.05 * view.radius, Math.min(50 * view.radius, cam.dist * Math.exp(e.deltaY * 0.001)));
    redraw();
  }, {passive: false});
  canvas.addEventListener("dblclick", function () {
    cam.yaw = home.yaw; cam.pitch = home.pitch; cam.dist = home.dist; cam.target = home.target.slice();
    redraw();
  });
  document.querySelectorAll("input[data-show]").forEach(function (box) {
    var key = box.getAttribute("data-show");
    box.checked = show[key];
    box.addEventListener("change", function () { show[key] = box.checked; redraw(); });
  });
  window.addEventListener("resize", redraw);

  /* Rigs: view.instants holds the persons of every instant (joints flat, flags as digits:
     1 observed, 2 interpolated, 3 inferred); a slider picks the instant drawn. */
  function unpack(person) {
    if (!person.joints) {
      var joints = [], head = [0, 0, 0], n = 0;
      for (var j = 0; j < person.xyz.length / 3; j++) {
        var x = person.xyz[3 * j];
        joints.push(x === null ? null : [x, person.xyz[3 * j + 1], person.xyz[3 * j + 2]]);
        if (j < 5 && x !== null) { head[0] += x; head[1] += person.xyz[3 * j + 1]; head[2] += person.xyz[3 * j + 2]; n++; }
      }
      person.joints = joints;
      person.head = n ? [head[0] / n, head[1] / n, head[2] / n + 0.08 * view.person_scale] : null;
    }
    return person;
  }
  var slider = document.getElementById("mvm-time");
  if (view.instants && slider) {
    var label = document.getElementById("mvm-time-label"), play = document.getElementById("mvm-play"), timer = null;
    var pick = function (i) {
      var instant = view.instants[i];
      view.persons = instant.persons.map(unpack);
      if (instant.truth) { view.truth = instant.truth.map(unpack); }
      if (label) { label.textContent = "frame " + instant.frame + " (" + (i + 1) + " / " + view.instants.length + ")"; }
      status.setAttribute("data-instant", String(i));
      redraw();
    };
    slider.max = String(view.instants.length - 1);
    slider.addEventListener("input", function () { pick(Number(slider.value)); });
    if (play) {
      play.addEventListener("click", function () {
        if (timer) { window.clearInterval(timer); timer = null; play.textContent = "play"; return; }
        play.textContent = "pause";
        timer = window.setInterval(function () {
          slider.value = String((Number(slider.value) + 1) % view.instants.length);
          pick(Number(slider.value));
        }, 1000 / (view.rate || 10));
      });
    }
    pick(0);
  }

  var count = draw();
  var rect = canvas.getBoundingClientRect();
  status.setAttribute("data-segments", String(count));
  status.setAttribute("data-canvas", [rect.left + window.scrollX, rect.top + window.scrollY, rect.width, rect.height].map(Math.round).join(","));
  status.setAttribute("data-render-ms", performance.now().toFixed(1));
  status.setAttribute("data-state", window.mvmErrors && window.mvmErrors.length ? "error" : "rendered");
  status.textContent = "3D view: " + view.persons.length + " persons";
}());

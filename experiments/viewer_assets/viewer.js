/* rtfit report image viewer: plain JavaScript, no network, works from file://.
 *
 * Input: a <script type="application/json"> manifest (cases, approximations, colour maps) named by the
 * data-manifest attribute of each .rtfit-viewer element, and per case a data script (viewer/data/CASE.js)
 * that assigns base64 little-endian float32 arrays to window.RTFIT_VIEWER_DATA[CASE]: reference and
 * stderr (H*W*3, row-major, top row first), mask (H*W uint8), approx/METHOD (H*W*3) and flip/METHOD
 * (H*W). Data scripts are loaded on demand with a <script> element (fetch() of local files is blocked
 * under file:// in Chromium); a single-file report has them inline already.
 *
 * Derived maps, per channel c or on the Rec. 709 luminance Y: signed error d = x - r; relative error
 * d / sqrt(r^2 + eps) (eps = manifest.rel_eps; its mean square is the report's relMSE); z = d / sigma.
 * sigma_Y = sum_c w_c sigma_c (channels of one path-traced estimate taken as fully correlated: exact
 * for grey scenes, an upper bound otherwise). Radiance is shown as 2^EV * value, sRGB-encoded, clipped.
 */
(function () {
  "use strict";

  var LUMA = [0.2126, 0.7152, 0.0722];
  var KINDS = {
    radiance: { title: "radiance", unit: "" },
    stderr: { title: "standard error σ", cmap: "sequential" },
    signed: { title: "signed error Δ = x − r", cmap: "diverging" },
    rel: { title: "relative error Δ/√(r² + ε)", cmap: "diverging" },
    z: { title: "z = Δ/σ", cmap: "diverging" },
    flip: { title: "ꟻLIP error", cmap: "flip" },
  };

  function el(tag, attrs, children) {
    var e = document.createElement(tag);
    if (attrs) {
      Object.keys(attrs).forEach(function (k) {
        if (k === "text") e.textContent = attrs[k];
        else if (k === "class") e.className = attrs[k];
        else e.setAttribute(k, attrs[k]);
      });
    }
    (children || []).forEach(function (c) {
      e.appendChild(typeof c === "string" ? document.createTextNode(c) : c);
    });
    return e;
  }

  function decode(b64, Type) {
    var bin = atob(b64);
    var u8 = new Uint8Array(bin.length);
    for (var i = 0; i < bin.length; i++) u8[i] = bin.charCodeAt(i);
    return new Type(u8.buffer);
  }

  function fmt(v) {
    if (v === null || v === undefined || Number.isNaN(v)) return "—";
    if (!Number.isFinite(v)) return v > 0 ? "∞" : "−∞";
    if (v === 0) return "0";
    var a = Math.abs(v);
    var s = a < 1e-3 || a >= 1e5 ? v.toExponential(4) : v.toPrecision(6);
    return s.replace("-", "−");
  }

  function short(v) {
    if (!Number.isFinite(v) || v === 0) return fmt(v);
    var a = Math.abs(v);
    return (a < 1e-3 || a >= 1e5 ? v.toExponential(2) : String(Number(v.toPrecision(3)))).replace("-", "−");
  }

  function srgb8(x) {
    if (!(x > 0)) return 0;
    if (x >= 1) return 255;
    var s = x <= 0.0031308 ? 12.92 * x : 1.055 * Math.pow(x, 1 / 2.4) - 0.055;
    return Math.round(s * 255);
  }

  function percentile(values, q) {
    if (!values.length) return 0;
    var s = Float64Array.from(values).sort();
    return s[Math.min(s.length - 1, Math.floor(q * (s.length - 1) + 0.5))];
  }

  function loadCase(entry) {
    return new Promise(function (resolve, reject) {
      var store = window.RTFIT_VIEWER_DATA || {};
      if (store[entry.id]) return resolve(store[entry.id]);
      var s = document.createElement("script");
      s.src = entry.script;
      s.onload = function () {
        var d = (window.RTFIT_VIEWER_DATA || {})[entry.id];
        if (d) resolve(d);
        else reject(new Error(entry.script + " did not define the data of case " + entry.id));
      };
      s.onerror = function () {
        reject(new Error("cannot load " + entry.script + " (the viewer/ folder must sit beside the report)"));
      };
      document.head.appendChild(s);
    });
  }

  function Viewer(root, manifest) {
    this.root = root;
    this.m = manifest;
    this.state = { caseIndex: -1, a: "reference", b: null, ev: 0, channel: "Y", range: null, wipe: 0.5 };
    this.view = { scale: 1, ox: 0, oy: 0 };
    this.data = null;
    this.pinned = null;
    this.hover = null;
    this.build();
  }

  Viewer.prototype.build = function () {
    var self = this;
    var m = this.m;
    this.root.textContent = "";
    var caseSel = el("select", { class: "rv-case", "aria-label": "case" });
    m.cases.forEach(function (c, i) {
      caseSel.appendChild(el("option", { value: String(i), text: c.label + " (" + c.id + ")" }));
    });
    this.aSel = el("select", { class: "rv-a", "aria-label": "image A" });
    this.bSel = el("select", { class: "rv-b", "aria-label": "image B" });
    this.ev = el("input", { class: "rv-ev", type: "range", min: "-12", max: "12", step: "0.1", value: "0" });
    this.evOut = el("output", { class: "rv-ev-value", text: "+0.0 EV" });
    var autoEv = el("button", { type: "button", class: "rv-auto", text: "auto", title: "white = 99.5th percentile of the reference" });
    this.channel = el("select", { class: "rv-channel", "aria-label": "channel of the error maps" });
    [["Y", "luminance Y"], ["R", "R"], ["G", "G"], ["B", "B"]].forEach(function (o) {
      self.channel.appendChild(el("option", { value: o[0], text: o[1] }));
    });
    this.range = el("input", { class: "rv-range", type: "text", size: "8", placeholder: "auto", title: "false-colour range: ± this value (σ for z); empty: automatic" });
    this.wipe = el("input", { class: "rv-wipe", type: "range", min: "0", max: "1000", step: "1", value: "500", "aria-label": "wipe position" });
    var fit = el("button", { type: "button", class: "rv-fit", text: "fit" });
    var one = el("button", { type: "button", class: "rv-one", text: "1:1" });
    var swap = el("button", { type: "button", class: "rv-swap", text: "A ⇄ B" });
    this.zoomOut = el("span", { class: "rv-zoom", text: "" });
    var row0 = el("div", { class: "rv-controls" }, [el("label", null, ["case ", caseSel])]);
    var row1 = el("div", { class: "rv-controls" }, [
      el("label", null, ["A ", this.aSel]),
      swap,
      el("label", null, ["B ", this.bSel]),
    ]);
    var row2 = el("div", { class: "rv-controls" }, [
      el("label", null, ["exposure ", this.ev]), this.evOut, autoEv,
      el("label", null, ["maps on ", this.channel]),
      el("label", null, ["range ± ", this.range]),
      el("label", null, ["wipe ", this.wipe]),
      fit, one, this.zoomOut,
    ]);
    this.canvas = el("canvas", { class: "rv-canvas", tabindex: "0" });
    this.stage = el("div", { class: "rv-stage" }, [this.canvas]);
    this.bars = el("div", { class: "rv-bars" });
    this.readout = el("div", { class: "rv-readout" });
    this.status = el("div", { class: "rv-status", role: "status" });
    this.note = el("p", { class: "rv-note" });
    this.root.appendChild(row0);
    this.root.appendChild(row1);
    this.root.appendChild(row2);
    this.root.appendChild(this.status);
    this.root.appendChild(this.stage);
    this.root.appendChild(this.bars);
    this.root.appendChild(this.readout);
    this.root.appendChild(this.note);

    caseSel.addEventListener("change", function () { self.setCase(Number(caseSel.value)); });
    this.caseSel = caseSel;
    this.aSel.addEventListener("change", function () { self.set({ a: self.aSel.value }); });
    this.bSel.addEventListener("change", function () { self.set({ b: self.bSel.value }); });
    swap.addEventListener("click", function () { self.set({ a: self.state.b, b: self.state.a }); });
    this.ev.addEventListener("input", function () { self.set({ ev: Number(self.ev.value) }); });
    autoEv.addEventListener("click", function () { self.set({ ev: self.autoExposure() }); });
    this.channel.addEventListener("change", function () { self.set({ channel: self.channel.value }); });
    this.range.addEventListener("change", function () {
      var v = parseFloat(self.range.value);
      self.set({ range: v > 0 ? v : null });
    });
    this.wipe.addEventListener("input", function () { self.set({ wipe: Number(self.wipe.value) / 1000 }); });
    fit.addEventListener("click", function () { self.fit(); });
    one.addEventListener("click", function () { self.zoomAbout(1 / self.view.scale, self.cssW / 2, self.cssH / 2); });
    this.bindPointer();
    window.addEventListener("resize", function () { self.resize(); });
    this.resize();
    this.setCase(0);
  };

  // ------------------------------------------------------------------------------------ data
  Viewer.prototype.setCase = function (i) {
    var self = this;
    var entry = this.m.cases[i];
    this.state.caseIndex = i;
    this.caseSel.value = String(i);
    this.root.setAttribute("data-state", "loading");
    this.status.textContent = "loading " + entry.id + " …";
    return loadCase(entry).then(function (raw) {
      if (self.state.caseIndex !== i) return;
      var n = entry.width * entry.height;
      var d = { entry: entry, w: entry.width, h: entry.height, approx: {}, flip: {} };
      d.ref = decode(raw.reference, Float32Array);
      d.se = decode(raw.stderr, Float32Array);
      d.mask = decode(raw.mask, Uint8Array);
      if (d.ref.length !== 3 * n || d.se.length !== 3 * n || d.mask.length !== n) {
        throw new Error("data of case " + entry.id + " do not match its size " + entry.width + "×" + entry.height);
      }
      entry.approximations.forEach(function (a) {
        d.approx[a.method] = decode(raw["approx/" + a.method], Float32Array);
        if (raw["flip/" + a.method]) d.flip[a.method] = decode(raw["flip/" + a.method], Float32Array);
      });
      self.data = d;
      self.images = self.imageList(d);
      var keys = self.images.map(function (x) { return x.key; });
      var first = entry.approximations.length ? "approx/" + entry.approximations[0].method : "reference";
      self.state.a = keys.indexOf(self.state.a) >= 0 ? self.state.a : "reference";
      self.state.b = keys.indexOf(self.state.b) >= 0 ? self.state.b : first;
      self.fillSelect(self.aSel);
      self.fillSelect(self.bSel);
      self.set({ ev: self.autoExposure() });
      self.note.textContent = entry.flip_note ? "ꟻLIP map not available: " + entry.flip_note : "";
      self.status.textContent = "";
      self.fit();
      self.root.setAttribute("data-state", "ready");
    }).catch(function (err) {
      self.status.textContent = "Viewer: " + err.message;
      self.root.setAttribute("data-state", "error");
      throw err;
    });
  };

  Viewer.prototype.imageList = function (d) {
    var list = [
      { key: "reference", label: "reference", kind: "radiance", group: "reference" },
      { key: "stderr", label: "reference σ", kind: "stderr", group: "reference" },
    ];
    d.entry.approximations.forEach(function (a) {
      var m = a.method;
      var g = a.label;
      list.push({ key: "approx/" + m, label: a.label, kind: "radiance", method: m, group: g });
      list.push({ key: "signed/" + m, label: "Δ " + a.label, kind: "signed", method: m, group: g });
      list.push({ key: "rel/" + m, label: "rel. Δ " + a.label, kind: "rel", method: m, group: g });
      list.push({ key: "z/" + m, label: "z " + a.label, kind: "z", method: m, group: g });
      if (d.flip[m]) list.push({ key: "flip/" + m, label: "ꟻLIP " + a.label, kind: "flip", method: m, group: g });
    });
    return list;
  };

  Viewer.prototype.fillSelect = function (sel) {
    sel.textContent = "";
    var groups = {};
    this.images.forEach(function (im) {
      if (!groups[im.group]) {
        groups[im.group] = el("optgroup", { label: im.group });
        sel.appendChild(groups[im.group]);
      }
      var kind = im.kind === "radiance" ? "" : " — " + KINDS[im.kind].title;
      groups[im.group].appendChild(el("option", { value: im.key, text: im.label + kind }));
    });
    sel.value = sel === this.aSel ? this.state.a : this.state.b;
  };

  Viewer.prototype.image = function (key) {
    for (var i = 0; i < this.images.length; i++) if (this.images[i].key === key) return this.images[i];
    return this.images[0];
  };

  Viewer.prototype.autoExposure = function () {
    var d = this.data;
    var vals = [];
    for (var p = 0; p < d.w * d.h; p++) {
      if (!d.mask[p]) continue;
      vals.push(Math.max(d.ref[3 * p], d.ref[3 * p + 1], d.ref[3 * p + 2]));
    }
    if (!vals.length) for (var q = 0; q < d.ref.length; q++) vals.push(d.ref[q]);
    var white = percentile(vals, 0.995);
    return white > 0 ? Math.round(-Math.log2(white) * 10) / 10 : 0;
  };

  // Scalar field of a false-colour image at pixel p (channel selection applied).
  Viewer.prototype.scalar = function (im, p) {
    var d = this.data;
    var ch = this.state.channel;
    var eps = this.m.rel_eps;
    if (im.kind === "flip") return d.flip[im.method][p];
    var r, s, x;
    if (ch === "Y") {
      r = 0; s = 0; x = 0;
      for (var c = 0; c < 3; c++) {
        r += LUMA[c] * d.ref[3 * p + c];
        s += LUMA[c] * d.se[3 * p + c];
        if (im.method) x += LUMA[c] * d.approx[im.method][3 * p + c];
      }
    } else {
      var k = "RGB".indexOf(ch);
      r = d.ref[3 * p + k];
      s = d.se[3 * p + k];
      x = im.method ? d.approx[im.method][3 * p + k] : 0;
    }
    if (im.kind === "stderr") return s;
    var delta = x - r;
    if (im.kind === "signed") return delta;
    if (im.kind === "rel") return delta / Math.sqrt(r * r + eps);
    if (im.kind === "z") return s > 0 ? delta / s : delta === 0 ? 0 : delta > 0 ? Infinity : -Infinity;
    return NaN;
  };

  // Colour range [lo, hi] of a false-colour image; shared by A and B when they are of one kind.
  Viewer.prototype.rangeOf = function (im) {
    if (im.kind === "flip") return [0, 1];
    var self = this;
    var auto = function (one) {
      if (self.state.range) return self.state.range;
      if (one.kind === "z") return 4;
      var d = self.data;
      var vals = [];
      for (var p = 0; p < d.w * d.h; p++) {
        if (d.mask[p]) {
          var v = Math.abs(self.scalar(one, p));
          if (Number.isFinite(v)) vals.push(v);
        }
      }
      var q = percentile(vals, 0.99);
      if (!(q > 0)) q = vals.length ? Math.max.apply(null, vals) : 0;
      return q > 0 ? q : 1;
    };
    var a = this.image(this.state.a);
    var b = this.image(this.state.b);
    var r = auto(im);
    var other = im.key === a.key ? b : a;
    if (other.kind === im.kind && other.key !== im.key) r = Math.max(r, auto(other));
    return im.kind === "stderr" ? [0, r] : [-r, r];
  };

  Viewer.prototype.rasterise = function (im) {
    var d = this.data;
    var n = d.w * d.h;
    var out = new ImageData(d.w, d.h);
    var px = out.data;
    var info = { kind: im.kind };
    if (im.kind === "radiance") {
      var src = im.method ? d.approx[im.method] : d.ref;
      var g = Math.pow(2, this.state.ev);
      for (var p = 0; p < n; p++) {
        px[4 * p] = srgb8(g * src[3 * p]);
        px[4 * p + 1] = srgb8(g * src[3 * p + 1]);
        px[4 * p + 2] = srgb8(g * src[3 * p + 2]);
        px[4 * p + 3] = 255;
      }
      info.white = Math.pow(2, -this.state.ev);
    } else {
      var lut = this.m.colormaps[KINDS[im.kind].cmap];
      var rg = this.rangeOf(im);
      info.range = rg;
      for (var q = 0; q < n; q++) {
        var v = this.scalar(im, q);
        var t = (v - rg[0]) / (rg[1] - rg[0]);
        var i = Math.max(0, Math.min(255, Math.round((Number.isNaN(t) ? 0.5 : t) * 255)));
        var col = lut[i];
        var dim = d.mask[q] ? 1 : 0.35;
        px[4 * q] = Math.round(col[0] * dim + 60 * (1 - dim));
        px[4 * q + 1] = Math.round(col[1] * dim + 60 * (1 - dim));
        px[4 * q + 2] = Math.round(col[2] * dim + 60 * (1 - dim));
        px[4 * q + 3] = 255;
      }
    }
    var c = document.createElement("canvas");
    c.width = d.w;
    c.height = d.h;
    c.getContext("2d").putImageData(out, 0, 0);
    info.canvas = c;
    return info;
  };

  // ---------------------------------------------------------------------------------- state
  Viewer.prototype.set = function (patch) {
    Object.assign(this.state, patch);
    this.ev.value = String(this.state.ev);
    this.evOut.textContent = (this.state.ev >= 0 ? "+" : "−") + Math.abs(this.state.ev).toFixed(1) + " EV";
    this.wipe.value = String(Math.round(this.state.wipe * 1000));
    this.aSel.value = this.state.a;
    this.bSel.value = this.state.b;
    this.channel.value = this.state.channel;
    if (this.data) this.render();
  };

  Viewer.prototype.render = function () {
    var a = this.image(this.state.a);
    var b = this.image(this.state.b);
    this.layerA = this.rasterise(a);
    this.layerB = a.key === b.key ? this.layerA : this.rasterise(b);
    this.drawBars(a, b);
    this.draw();
    this.showReadout();
  };

  // ---------------------------------------------------------------------------------- view
  Viewer.prototype.resize = function () {
    var w = Math.max(200, this.stage.clientWidth || 600);
    var d = this.data;
    var aspect = d ? d.h / d.w : 0.6;
    var h = Math.round(Math.min(Math.max(220, w * aspect), (window.innerHeight || 800) * 0.7));
    var dpr = window.devicePixelRatio || 1;
    this.cssW = w;
    this.cssH = h;
    this.canvas.style.width = w + "px";
    this.canvas.style.height = h + "px";
    this.canvas.width = Math.round(w * dpr);
    this.canvas.height = Math.round(h * dpr);
    this.dpr = dpr;
    if (this.data) this.draw();
  };

  Viewer.prototype.fit = function () {
    this.resize();
    var d = this.data;
    if (!d) return;
    var s = Math.min(this.cssW / d.w, this.cssH / d.h);
    this.view = { scale: s, ox: (this.cssW - s * d.w) / 2, oy: (this.cssH - s * d.h) / 2 };
    this.draw();
  };

  Viewer.prototype.zoomAbout = function (factor, cx, cy) {
    var v = this.view;
    var s = Math.min(256, Math.max(0.05, v.scale * factor));
    factor = s / v.scale;
    this.view = { scale: s, ox: cx - (cx - v.ox) * factor, oy: cy - (cy - v.oy) * factor };
    this.draw();
  };

  Viewer.prototype.draw = function () {
    var ctx = this.canvas.getContext("2d");
    var d = this.data;
    ctx.setTransform(this.dpr, 0, 0, this.dpr, 0, 0);
    ctx.fillStyle = "#2b2b2e";
    ctx.fillRect(0, 0, this.cssW, this.cssH);
    if (!d || !this.layerA) return;
    var v = this.view;
    ctx.imageSmoothingEnabled = false;
    var split = v.ox + this.state.wipe * d.w * v.scale;
    var self = this;
    [[this.layerA, 0, split], [this.layerB, split, this.cssW]].forEach(function (part) {
      var x0 = Math.max(0, part[1]);
      var x1 = Math.min(self.cssW, part[2]);
      if (x1 <= x0) return;
      ctx.save();
      ctx.beginPath();
      ctx.rect(x0, 0, x1 - x0, self.cssH);
      ctx.clip();
      ctx.drawImage(part[0].canvas, v.ox, v.oy, d.w * v.scale, d.h * v.scale);
      ctx.restore();
    });
    if (split > 0 && split < this.cssW) {
      ctx.fillStyle = "rgba(255,255,255,0.9)";
      ctx.fillRect(split - 1, 0, 2, this.cssH);
      ctx.beginPath();
      ctx.arc(split, this.cssH / 2, 7, 0, 2 * Math.PI);
      ctx.fill();
    }
    var p = this.pinned || this.hover;
    if (p && v.scale >= 4) {
      ctx.strokeStyle = "#ffcc00";
      ctx.lineWidth = 1;
      ctx.strokeRect(v.ox + p[0] * v.scale + 0.5, v.oy + p[1] * v.scale + 0.5, v.scale - 1, v.scale - 1);
    }
    ctx.font = "12px -apple-system, 'Segoe UI', Arial, sans-serif";
    ctx.textBaseline = "top";
    var label = function (text, x, align) {
      ctx.textAlign = align;
      var w = ctx.measureText(text).width;
      ctx.fillStyle = "rgba(0,0,0,0.6)";
      ctx.fillRect(align === "left" ? x - 4 : x - w - 4, 6, w + 8, 18);
      ctx.fillStyle = "#fff";
      ctx.fillText(text, x, 9);
    };
    label("A: " + this.image(this.state.a).label, 10, "left");
    label("B: " + this.image(this.state.b).label, this.cssW - 10, "right");
    this.zoomOut.textContent = "zoom ×" + (v.scale >= 10 ? v.scale.toFixed(0) : v.scale.toFixed(2));
  };

  Viewer.prototype.pixelAt = function (cx, cy) {
    var v = this.view;
    var d = this.data;
    var x = Math.floor((cx - v.ox) / v.scale);
    var y = Math.floor((cy - v.oy) / v.scale);
    return d && x >= 0 && y >= 0 && x < d.w && y < d.h ? [x, y] : null;
  };

  /** Page (client) coordinates of the centre of pixel (x, y): for tests and scripting. */
  Viewer.prototype.clientPoint = function (x, y) {
    var r = this.canvas.getBoundingClientRect();
    return [r.left + this.view.ox + (x + 0.5) * this.view.scale, r.top + this.view.oy + (y + 0.5) * this.view.scale];
  };

  Viewer.prototype.bindPointer = function () {
    var self = this;
    var c = this.canvas;
    var drag = null;
    var local = function (e) {
      var r = c.getBoundingClientRect();
      return [e.clientX - r.left, e.clientY - r.top];
    };
    c.addEventListener("wheel", function (e) {
      e.preventDefault();
      var p = local(e);
      self.zoomAbout(Math.pow(1.0015, -e.deltaY), p[0], p[1]);
    }, { passive: false });
    c.addEventListener("pointerdown", function (e) {
      var p = local(e);
      var split = self.view.ox + self.state.wipe * (self.data ? self.data.w : 0) * self.view.scale;
      drag = { x: p[0], y: p[1], ox: self.view.ox, oy: self.view.oy, wipe: Math.abs(p[0] - split) < 9, moved: false };
      c.setPointerCapture(e.pointerId);
    });
    c.addEventListener("pointermove", function (e) {
      var p = local(e);
      if (drag) {
        if (Math.abs(p[0] - drag.x) + Math.abs(p[1] - drag.y) > 3) drag.moved = true;
        if (drag.wipe && self.data) {
          var u = (p[0] - self.view.ox) / (self.data.w * self.view.scale);
          self.set({ wipe: Math.max(0, Math.min(1, u)) });
          return;
        }
        if (drag.moved) {
          self.view.ox = drag.ox + p[0] - drag.x;
          self.view.oy = drag.oy + p[1] - drag.y;
          self.draw();
          return;
        }
      }
      self.hover = self.pixelAt(p[0], p[1]);
      if (!self.pinned) self.showReadout();
      self.draw();
    });
    c.addEventListener("pointerup", function (e) {
      if (drag && !drag.moved && !drag.wipe) {
        var px = self.pixelAt(local(e)[0], local(e)[1]);
        self.pinned = self.pinned || !px ? null : px;
        self.showReadout();
        self.draw();
      }
      drag = null;
    });
    c.addEventListener("pointerleave", function () {
      self.hover = null;
      if (!self.pinned) self.showReadout();
      self.draw();
    });
    c.addEventListener("dblclick", function () { self.fit(); });
  };

  // --------------------------------------------------------------------------------- readout
  Viewer.prototype.showReadout = function () {
    var d = this.data;
    var p = this.pinned || this.hover;
    this.readout.textContent = "";
    if (!d) return;
    if (!p) {
      this.readout.appendChild(el("p", { class: "rv-hint", text: "Point at a pixel for its values (click to pin)." }));
      return;
    }
    var i = p[1] * d.w + p[0];
    var trip = function (arr) { return [arr[3 * i], arr[3 * i + 1], arr[3 * i + 2]]; };
    var ref = trip(d.ref);
    var se = trip(d.se);
    var layers = [ref, se];
    d.entry.approximations.forEach(function (a) { layers.push(trip(d.approx[a.method])); });
    var grey = layers.every(function (t) { return t[0] === t[1] && t[1] === t[2]; });
    // One number per cell for a grey pixel; else R, G, B stacked in each cell (one line per channel).
    var cell = function (t, cls) {
      var td = el("td", cls ? { class: cls } : null);
      (grey ? [t[0]] : t).forEach(function (v, c) {
        if (c) td.appendChild(el("br"));
        td.appendChild(document.createTextNode(fmt(v)));
      });
      return td;
    };
    var blank = function () { return el("td", { text: "" }); };
    var channels = el("td", { class: "rv-ch" });
    if (!grey) channels.innerHTML = "R<br>G<br>B";
    var head = el("p", { class: "rv-where" }, [
      (this.pinned ? "pinned " : "") + "pixel x = " + p[0] + ", y = " + p[1] + " · " + (d.mask[i] ? "inside" : "outside") +
        " the comparison mask" + (grey ? " · R = G = B" : ""),
    ]);
    var table = el("table", { class: "rv-table" });
    table.appendChild(el("thead", null, [el("tr", null, [
      el("th", { text: "" }), el("th", { text: "" }), el("th", { text: "value" }), el("th", { text: "σ" }),
      el("th", { text: "Δ = x − r" }), el("th", { text: "z = Δ/σ" }), el("th", { text: "ꟻLIP" }),
    ])]));
    var body = el("tbody");
    body.appendChild(el("tr", { class: "rv-ref" }, [
      el("th", { text: "reference r" }), channels.cloneNode(true), cell(ref, "rv-ref-value"), cell(se, "rv-ref-sigma"),
      blank(), blank(), blank(),
    ]));
    var self = this;
    d.entry.approximations.forEach(function (a) {
      var x = trip(d.approx[a.method]);
      var dl = [x[0] - ref[0], x[1] - ref[1], x[2] - ref[2]];
      var z = dl.map(function (v, c) { return se[c] > 0 ? v / se[c] : v === 0 ? 0 : v > 0 ? Infinity : -Infinity; });
      var f = el("td", { text: d.flip[a.method] ? fmt(d.flip[a.method][i]) : "—" });
      var shown = [self.image(self.state.a).method, self.image(self.state.b).method].indexOf(a.method) >= 0;
      body.appendChild(el("tr", { class: shown ? "rv-shown" : "" }, [
        el("th", { text: a.label }), channels.cloneNode(true), cell(x), blank(), cell(dl), cell(z), f,
      ]));
    });
    table.appendChild(body);
    this.readout.appendChild(head);
    this.readout.appendChild(table);
  };

  // ------------------------------------------------------------------------------------ bars
  Viewer.prototype.drawBars = function (a, b) {
    var self = this;
    this.bars.textContent = "";
    var seen = {};
    [["A", a, this.layerA], ["B", b, this.layerB]].forEach(function (x) {
      var im = x[1];
      var info = x[2];
      var sig = im.kind === "radiance" ? "radiance" : im.kind + info.range.join(",");
      var tag = seen[sig] ? null : x[0];
      if (!tag) { seen[sig].textContent = "A, B: "; return; }
      var bar = document.createElement("canvas");
      bar.width = 256;
      bar.height = 1;
      var ctx = bar.getContext("2d");
      var img = ctx.createImageData(256, 1);
      for (var i = 0; i < 256; i++) {
        var col;
        if (im.kind === "radiance") {
          var g = srgb8(i / 255);
          col = [g, g, g];
        } else col = self.m.colormaps[KINDS[im.kind].cmap][i];
        img.data.set([col[0], col[1], col[2], 255], 4 * i);
      }
      ctx.putImageData(img, 0, 0);
      bar.className = "rv-bar";
      var lo, mid, hi, title;
      if (im.kind === "radiance") {
        lo = "0"; mid = short(info.white / 2); hi = short(info.white);
        title = "radiance × 2^" + self.state.ev.toFixed(1).replace("-", "−") + ", sRGB-encoded; white = " + short(info.white) + " (brighter clips)";
      } else {
        lo = short(info.range[0]); hi = short(info.range[1]); mid = short((info.range[0] + info.range[1]) / 2);
        var ch = self.state.channel === "Y" ? "luminance Y" : "channel " + self.state.channel;
        title = KINDS[im.kind].title + (im.kind === "flip" ? "" : ", " + ch) + (im.kind === "z" ? " (σ units)" : "") + (im.kind === "rel" ? ", ε = " + self.m.rel_eps : "");
      }
      var who = el("span", { class: "rv-bar-who", text: tag + ": " });
      seen[sig] = who;
      self.bars.appendChild(el("div", { class: "rv-bar-row" }, [
        el("div", { class: "rv-bar-title" }, [who, title]),
        bar,
        el("div", { class: "rv-bar-labels" }, [el("span", { text: lo }), el("span", { text: mid }), el("span", { text: hi })]),
      ]));
    });
  };

  function start() {
    var api = (window.RTFIT_VIEWER = window.RTFIT_VIEWER || { instances: [] });
    var roots = document.querySelectorAll(".rtfit-viewer");
    for (var i = 0; i < roots.length; i++) {
      var root = roots[i];
      if (root.getAttribute("data-started")) continue;
      root.setAttribute("data-started", "1");
      var m = document.getElementById(root.getAttribute("data-manifest"));
      if (!m) continue;
      var manifest = JSON.parse(m.textContent);
      if (!manifest.cases || !manifest.cases.length) continue;
      api.instances.push(new Viewer(root, manifest));
    }
  }

  if (document.readyState === "loading") document.addEventListener("DOMContentLoaded", start);
  else start();
})();

// spacearm job page: follows the job over its Server-Sent Events stream (a file, not inline: the
// pages' CSP allows scripts from this site only).
//
// The convergence figure is re-rendered at most one at a time: a generation that arrives while a
// render is loading only marks the newest version wanted, and that one is loaded next, so renders
// never queue behind each other and the figure trails the job by about one render.
(function () {
  var jobId = document.body.dataset.jobId;
  var base = "/v1/tuning-jobs/" + jobId;
  var img = document.getElementById("convergence");
  var figure = {loading: false, wanted: null, shown: null, since: {}};
  window.spacearmFigureLags = [];  // seconds from an event to its figure on screen (read by the browser test)

  function fmt(x) { return (x === null || x === undefined) ? "—" : Number(x).toPrecision(4); }
  function params(p) { return p ? Object.keys(p).map(function (k) { return k + "=" + fmt(p[k]); }).join(" ") : ""; }
  function text(id, value) { document.getElementById(id).textContent = value; }

  function loadFigure() {
    var version = figure.wanted;
    if (figure.loading || version === null || version === figure.shown) { return; }
    figure.loading = true;
    var next = new Image();
    next.onload = next.onerror = function () {
      if (next.naturalWidth) {
        img.src = next.src;
        img.dataset.version = version;
        window.spacearmFigureLags.push((performance.now() - figure.since[version]) / 1000);
      }
      figure.shown = version;
      figure.loading = false;
      loadFigure();  // a newer version may have been wanted meanwhile
    };
    next.src = base + "/figures/convergence?v=" + encodeURIComponent(version);
  }

  function wantFigure(version) {
    if (!(version in figure.since)) { figure.since[version] = performance.now(); }
    figure.wanted = version;
    loadFigure();
  }

  function showStatus(s) {
    text("job-status", s.status);
    text("job-progress", "generation " + (s.generation || 0) + " / " + (s.generations || 0) + " (all phases)");
    document.getElementById("job-bar").style.width = (s.generations ? 100 * s.generation / s.generations : 0) + "%";
    text("job-best", fmt(s.best_objective_b));
    text("job-params", params(s.best_params));
    text("job-evals", s.evaluations || 0);
    if (s.error) { var e = document.getElementById("job-error"); e.hidden = false; e.textContent = s.error; }
  }

  function showResult() {
    fetch(base + "/result").then(function (r) { return r.json(); }).then(function (res) {
      var d = res.dls_baseline, b = res.bounded_baseline;
      var t = document.createElement("p");
      t.id = "job-result-text";
      t.textContent = "Result: B = " + fmt(res.best_objective_b) + " with " + params(res.best_params) +
        (d ? "; DLS baseline B = " + fmt(d.objective_b) + " (lambda=" + fmt(d.lambda) + "), improvement " +
         fmt(res.improvement_over_dls_percent) + " %" : "") +
        (b ? "; bounded inverse B = " + fmt(b.objective_b) + " (lambda=" + fmt(b.lambda) + ")" +
         (d ? ", " + fmt(res.bounded_improvement_over_dls_percent) + " % against DLS" : "") : "") +
        ((res.warnings || []).length ? " — " + res.warnings.join("; ") : "");
      var box = document.getElementById("job-result");
      box.innerHTML = "";
      box.appendChild(t);
    });
  }

  var stream = new EventSource(base + "/events");
  stream.addEventListener("status", function (e) {
    var s = JSON.parse(e.data);
    showStatus(s);
    wantFigure(s.status + ":" + s.generation);
  });
  stream.addEventListener("generation", function (e) {
    var g = JSON.parse(e.data);
    var phase = g.role === "dls_baseline" ? "DLS baseline" : g.role === "bounded_baseline" ? "bounded inverse" : g.phase;
    text("job-phase", phase + ": generation " + g.generation + " / " + g.generations);
    text("job-best", fmt(g.best));
    wantFigure(e.lastEventId);
  });
  stream.addEventListener("end", function (e) {
    stream.close();
    var s = JSON.parse(e.data);
    text("job-status", s.status);
    wantFigure("end:" + s.status);
    if (s.status === "succeeded") { showResult(); }
  });
})();

// spacearm job page: follows the job (a file, not inline: the pages' CSP allows scripts from this site only)
(function () {
  var jobId = document.body.dataset.jobId;
  var last = null;
  function fmt(x) { return (x === null || x === undefined) ? "—" : Number(x).toPrecision(4); }
  function params(p) { return p ? Object.keys(p).map(function (k) { return k + "=" + fmt(p[k]); }).join(" ") : ""; }
  function poll() {
    fetch("/v1/tuning-jobs/" + jobId, {headers: {"accept": "application/json"}})
      .then(function (r) { return r.json(); })
      .then(function (job) {
        var p = job.progress || {};
        document.getElementById("job-status").textContent = job.status;
        document.getElementById("job-progress").textContent = "generation " + (p.generation || 0) + " / " + (p.generations || 0);
        document.getElementById("job-bar").style.width = (p.generations ? 100 * p.generation / p.generations : 0) + "%";
        document.getElementById("job-phase").textContent = p.phase || "—";
        document.getElementById("job-best").textContent = fmt(p.best_objective_b);
        document.getElementById("job-params").textContent = params(p.best_params);
        document.getElementById("job-evals").textContent = p.evaluations || 0;
        if (job.error) { var e = document.getElementById("job-error"); e.hidden = false; e.textContent = job.error; }
        var stamp = job.status + ":" + p.generation + ":" + p.phase;
        if (stamp !== last) {
          last = stamp;
          document.getElementById("convergence").src = "/v1/tuning-jobs/" + jobId + "/figures/convergence?v=" + encodeURIComponent(stamp);
        }
        if (job.status === "succeeded") {
          fetch("/v1/tuning-jobs/" + jobId + "/result").then(function (r) { return r.json(); }).then(function (res) {
            var d = res.dls_baseline;
            document.getElementById("job-result").innerHTML = "";
            var t = document.createElement("p");
            t.id = "job-result-text";
            t.textContent = "Result: B = " + fmt(res.best_objective_b) + " with " + params(res.best_params) +
              (d ? "; DLS baseline B = " + fmt(d.objective_b) + " (lambda=" + fmt(d.lambda) + "), improvement " +
               fmt(res.improvement_over_dls_percent) + " %" : "");
            document.getElementById("job-result").appendChild(t);
          });
        }
        if (["succeeded", "failed", "cancelled"].indexOf(job.status) < 0) { setTimeout(poll, 1000); }
      })
      .catch(function () { setTimeout(poll, 2000); });
  }
  poll();
})();

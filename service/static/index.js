// spacearm pages (a file, not inline: the pages' CSP allows scripts from this site only)
(function () {
  // the plan form: show only the parameters of the chosen method (without JavaScript all are
  // shown; only the chosen one is used)
  var select = document.getElementById("method");
  if (select) {
    var update = function () {
      document.querySelectorAll(".method-params").forEach(function (row) {
        row.style.display = row.dataset.method === select.value ? "" : "none";
      });
    };
    select.addEventListener("change", update);
    update();
  }
  // a delete asks first (without JavaScript it deletes at once)
  document.querySelectorAll("form.delete-form").forEach(function (form) {
    form.addEventListener("submit", function (event) {
      var what = form.querySelector("button").dataset.delete.split(":")[0].replace(/s$/, "").replace("-", " ");
      if (!window.confirm("Delete this " + what + "? This cannot be undone.")) { event.preventDefault(); }
    });
  });
})();

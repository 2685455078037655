// spacearm index page (a file, not inline: the pages' CSP allows scripts from this site only)
// show only the parameters of the chosen method (without JavaScript all are shown; only the chosen one is used)
(function () {
  var select = document.getElementById("method");
  function update() {
    document.querySelectorAll(".method-params").forEach(function (row) {
      row.style.display = row.dataset.method === select.value ? "" : "none";
    });
  }
  select.addEventListener("change", update);
  update();
})();

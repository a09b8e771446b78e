// stillpoint dashboard: applies the server's live dock (server-sent events) and asks before an
// action. Written for this project; no library.
(function () {
  "use strict";
  var view = document.getElementById("dockview");
  var live = document.getElementById("live");
  var pending = null;
  function apply() {
    var a = document.activeElement;
    if (a && view.contains(a) && a.tagName === "INPUT") { return; }  // never under the typing hand
    if (pending !== null) { view.innerHTML = pending; pending = null; }
  }
  if (view && view.dataset.live === "1" && window.EventSource) {
    var es = new EventSource("/events");
    es.onopen = function () { if (live) { live.textContent = "connected"; live.className = "on"; } };
    es.onerror = function () { if (live) { live.textContent = "reconnecting…"; live.className = "off"; } };
    es.onmessage = function (ev) { pending = JSON.parse(ev.data).html; apply(); };
    document.addEventListener("focusout", function () { setTimeout(apply, 0); });
  }
  document.addEventListener("submit", function (ev) {
    var f = ev.target;
    if (!f.classList || !f.classList.contains("act")) { return; }
    if (!window.confirm(f.dataset.confirm)) { ev.preventDefault(); return; }
    f.querySelector("input[name=confirm]").value = "yes";
    var who = document.getElementById("who");
    if (who) { f.querySelector("input[name=who]").value = who.value; }
  });
  var pr = document.getElementById("print");
  if (pr) { pr.addEventListener("click", function () { window.print(); }); }
})();

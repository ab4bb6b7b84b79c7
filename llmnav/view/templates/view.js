// Step selection: click a marker or a list entry, or press the left/right arrow keys (Home/End too).
// Plain JavaScript, no dependencies; it only shows and hides content that is already in the page.
(function () {
  "use strict";
  document.documentElement.classList.add("js");
  var sections = Array.prototype.slice.call(document.querySelectorAll("section.step"));
  if (!sections.length) { return; }
  var buttons = Array.prototype.slice.call(document.querySelectorAll("nav.steps button[data-step]"));
  var markers = Array.prototype.slice.call(document.querySelectorAll("svg.map .marker[data-step]"));
  var overlays = Array.prototype.slice.call(document.querySelectorAll("svg.map .overlay[data-step]"));
  var status = document.getElementById("step-status");
  var current = -1;

  function mark(list, index) {
    list.forEach(function (el) {
      var on = Number(el.getAttribute("data-step")) === index;
      el.classList.toggle("selected", on);
      if (el.tagName.toLowerCase() === "button") { el.setAttribute("aria-current", on ? "true" : "false"); }
    });
  }

  function select(index, focusList) {
    if (index < 0 || index >= sections.length) { return; }
    current = index;
    sections.forEach(function (s, i) { s.classList.toggle("selected", i === index); });
    mark(buttons, index); mark(markers, index); mark(overlays, index);
    var button = buttons[index];
    if (button) {
      // Scroll the list only, never the window (the map and the header stay where the reader left them).
      var list = document.getElementById("step-list"), item = button.parentNode;
      if (list && item) {
        if (item.offsetTop < list.scrollTop) { list.scrollTop = item.offsetTop; }
        else if (item.offsetTop + item.offsetHeight > list.scrollTop + list.clientHeight) {
          list.scrollTop = item.offsetTop + item.offsetHeight - list.clientHeight;
        }
      }
      if (focusList) { button.focus({ preventScroll: true }); }
    }
    if (status) { status.textContent = sections[index].getAttribute("aria-label") || ""; }
    if (history.replaceState) { history.replaceState(null, "", "#step=" + (index + 1)); }
  }

  buttons.forEach(function (b) {
    b.addEventListener("click", function () { select(Number(b.getAttribute("data-step")), false); });
  });
  markers.forEach(function (m) {
    m.addEventListener("click", function () { select(Number(m.getAttribute("data-step")), false); });
    m.addEventListener("keydown", function (e) {
      if (e.key === "Enter" || e.key === " ") { e.preventDefault(); select(Number(m.getAttribute("data-step")), false); }
    });
  });
  document.addEventListener("keydown", function (e) {
    var tag = (e.target && e.target.tagName || "").toLowerCase();
    if (tag === "input" || tag === "textarea" || e.altKey || e.ctrlKey || e.metaKey) { return; }
    if (e.key === "ArrowRight") { e.preventDefault(); select(Math.min(current + 1, sections.length - 1), true); }
    else if (e.key === "ArrowLeft") { e.preventDefault(); select(Math.max(current - 1, 0), true); }
    else if (e.key === "Home") { e.preventDefault(); select(0, true); }
    else if (e.key === "End") { e.preventDefault(); select(sections.length - 1, true); }
  });
  // "#step=K" (not an element id, so the browser does not scroll to it) opens decision K (1-based).
  var match = /^#step=(\d+)$/.exec(location.hash);
  select(match ? Math.min(Number(match[1]) - 1, sections.length - 1) : 0, false);
  window.llmnavView = { select: select, count: sections.length, current: function () { return current; } };
}());

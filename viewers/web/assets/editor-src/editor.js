// The page's code editor: CodeMirror 6 bound to the workbench's hidden "Code" text area.
//
// Loaded by viewers/web/code_editor.py (see there and docs/VIEWER.md for why this way).
// window.wartEditor.mount(host) turns a <div class="wart-editor" data-for=ID ...> into an
// editor whose text is the viser text area labelled by <label for=ID>:
//  - editor -> Python: every change is written into that text area as a user's typing
//    would (React's value setter + an "input" event), so viser sends it to the server
//    exactly as it sends typed text, in order before any later button click;
//  - Python -> editor: the server sets the text area's value (React writes the DOM
//    property); a poll every 150 ms notices a value the editor did not write and loads it.
//  - Check's problems: a <div class="wart-problems" data-for=ID data-problems=JSON>
//    (a viser HTML element the server rewrites) becomes lint diagnostics in the gutter.
//  - [data-wart-line=N] links anywhere in the page move the editor to line N.
import { EditorState } from "@codemirror/state";
import {
  EditorView, keymap, lineNumbers, highlightActiveLine, highlightActiveLineGutter,
  drawSelection, highlightSpecialChars, rectangularSelection, dropCursor,
} from "@codemirror/view";
import {
  defaultKeymap, history, historyKeymap, indentWithTab, indentLess, indentMore,
} from "@codemirror/commands";
import {
  indentUnit, bracketMatching, foldGutter, foldKeymap, syntaxHighlighting,
  defaultHighlightStyle, indentOnInput,
} from "@codemirror/language";
import { closeBrackets, closeBracketsKeymap } from "@codemirror/autocomplete";
import { search, searchKeymap, highlightSelectionMatches } from "@codemirror/search";
import { setDiagnostics, lintGutter } from "@codemirror/lint";
import { python } from "@codemirror/lang-python";

const views = new Map(); // element id -> {view, area, written}
// viser 1.1.1's page sends GUI messages through one 50 ms throttle that keeps only the
// newest: a button pressed within that window of an edit would replace the edit's text
// message, and the server would Check or Run the text before it. So a press that soon
// after an edit is held back until the edit has had time to leave.
const SETTLE_MS = 200;
let lastWrite = 0;

function findArea(id) {
  // viser draws <label for=id> in one box and the text area in the next (see labels.py).
  const label = document.querySelector(`label[for="${CSS.escape(id)}"]`);
  const own = label && label.parentElement && label.parentElement.parentElement;
  const box = own && own.nextElementSibling;
  return box ? box.querySelector("textarea") : null;
}

function hideArea(id, area) {
  // The label's box and the text area's box share a row: hide the row, keep the text area.
  const label = document.querySelector(`label[for="${CSS.escape(id)}"]`);
  const row = label && label.parentElement && label.parentElement.parentElement &&
    label.parentElement.parentElement.parentElement;
  if (row && row.contains(area)) row.style.display = "none";
  area.tabIndex = -1;
  area.setAttribute("aria-hidden", "true");
}

function writeArea(area, text, again) {
  const setter = Object.getOwnPropertyDescriptor(HTMLTextAreaElement.prototype, "value").set;
  setter.call(area, text);
  // Sending the same text again: React only reports a change from the value it last saw.
  if (again && area._valueTracker) area._valueTracker.setValue(text + "\u0000");
  area.dispatchEvent(new Event("input", { bubbles: true }));
  lastWrite = performance.now();
}

// The same throttle drops an edit's message when another input of the panel sends within
// 50 ms of it, and nothing tells the page. So after each burst of edits the whole text is
// sent again, twice (the server ignores a value it already has) -- but only in a quiet
// moment: a resend right after a click or a choice would drop that instead.
const RESEND_MS = [300, 1500];
const QUIET_MS = 80;
let lastActivity = 0;

function noteActivity(event) {
  const t = event.target;
  if (t && t.closest && (t.closest(".wart-editor") || t.getAttribute("aria-hidden") === "true")) {
    return; // the editor's own typing, or its write into the hidden text area
  }
  lastActivity = performance.now();
}

function forget(entry) {
  // A replaced or vanished editor: its pending resends would send its old text.
  for (const t of entry.resend || []) clearTimeout(t);
  entry.resend = [];
  entry.view.destroy();
}

function resendLater(entry, ms) {
  return setTimeout(() => {
    if (views.get(entry.id) !== entry || !entry.view.dom.isConnected) return;
    const text = entry.view.state.doc.toString();
    if (text !== entry.written || !entry.area.isConnected) return;
    // The server set another text since (a file opened): the next poll loads it, and
    // sending ours now would put the old text back over it.
    if (entry.area.value !== entry.written) return;
    if (performance.now() - lastActivity < QUIET_MS) {
      entry.resend.push(resendLater(entry, QUIET_MS)); // not now: try again shortly
      return;
    }
    writeArea(entry.area, text, true);
  }, ms);
}

function scheduleResend(entry) {
  for (const t of entry.resend || []) clearTimeout(t);
  entry.resend = [];
  for (const ms of RESEND_MS) entry.resend.push(resendLater(entry, ms));
}

function holdEarlyPress(event) {
  const button = event.target.closest && event.target.closest("button");
  if (!button || button.dataset.wartReplay) return;
  const wait = lastWrite + SETTLE_MS - performance.now();
  if (wait <= 0) return;
  event.preventDefault();
  event.stopImmediatePropagation();
  setTimeout(() => {
    button.dataset.wartReplay = "1";
    try { button.click(); } finally { delete button.dataset.wartReplay; }
  }, wait);
}

function clickButton(text) {
  for (const b of document.querySelectorAll("button")) {
    if (b.textContent.trim() === text && !b.disabled) { b.click(); return true; }
  }
  return false;
}

function applyProblems(entry, problems) {
  const doc = entry.view.state.doc;
  const diagnostics = [];
  for (const p of problems) {
    if (!p.line || p.line < 1) continue;
    const line = doc.line(Math.min(p.line, doc.lines));
    diagnostics.push({
      from: line.from, to: line.to, severity: p.severity || "error", message: p.message,
    });
  }
  entry.view.dispatch(setDiagnostics(entry.view.state, diagnostics));
  entry.problemsShown = diagnostics.length;
}

// The editor a problem's link belongs to: the one in the nearest folder around the link
// (a page holds several: an arena tab's workbench each, kept in the page while hidden).
// Without a link, the editor in sight. A view whose host React just replaced is still
// listed until the next poll: moving its cursor would be lost with it.
function editorFor(link) {
  for (let node = link; node && node.querySelectorAll; node = node.parentElement) {
    for (const host of node.querySelectorAll("div.wart-editor[data-for]")) {
      const entry = views.get(host.dataset.for);
      if (entry && entry.view.dom.isConnected) return entry;
    }
  }
  const live = [...views.values()].filter((e) => e.view.dom.isConnected);
  return live.find((e) => e.view.dom.offsetParent !== null) || live[0] || null;
}

function goToLine(n, link) {
  const entry = editorFor(link || null);
  if (!entry) return;
  const view = entry.view;
  const before = view.state.selection.main.head;
  const place = (onlyIfBack) => {
    const head = view.state.selection.main.head;
    if (onlyIfBack && head !== before) return; // moved since: the user's, keep it
    const doc = view.state.doc;
    const line = doc.line(Math.max(1, Math.min(n, doc.lines)));
    if (doc.lineAt(head).number !== line.number) {
      view.dispatch({ selection: { anchor: line.from }, scrollIntoView: true });
    }
  };
  // Focus first, then place. A link reached by keyboard (Enter) took the focus: on its
  // way back, the editor may read the browser's own selection -- its old cursor -- back
  // in. A guard (never observed: the misses once blamed on it were clicks landing beside
  // the link, fixed by acting on the press): place again if the cursor went back there.
  view.focus();
  place(false);
  for (const ms of [50, 250]) setTimeout(() => place(true), ms);
}

function mount(host) {
  const id = host.dataset.for;
  if (!id || host.dataset.mounted) return;
  const area = findArea(id);
  if (!area) return; // not drawn yet: the next poll tries again
  host.dataset.mounted = "1";
  const buttons = JSON.parse(host.dataset.keys || "{}");
  // The text area stays in the page (it is what viser reads) but out of sight and of Tab.
  hideArea(id, area);
  // React drew the host anew (its old editor went with the old host): start over, where
  // the user was. A busy page redraws it while they type: the keys that follow must land
  // in the new editor, at the same place (mount runs from a MutationObserver, before them).
  const old = views.get(id);
  let focused = false, selection = null;
  if (old) {
    const active = document.activeElement;
    focused = old.focused && (!active || active === document.body || old.view.dom.contains(active));
    selection = old.view.state.selection;
    views.delete(id);
    forget(old);
  }
  const entry = { id, view: null, area, written: area.value, problemsShown: 0, focused: false };
  const keys = [
    { key: "Mod-Enter", preventDefault: true, run: () => clickButton(buttons.check || "Check") },
    { key: "Mod-s", preventDefault: true, run: () => clickButton(buttons.save || "Save") },
    { key: "Tab", run: indentMore, shift: indentLess },
  ];
  const view = new EditorView({
    parent: host,
    state: EditorState.create({
      doc: area.value,
      extensions: [
        lineNumbers(), highlightActiveLineGutter(), highlightSpecialChars(), history(),
        foldGutter(), drawSelection(), dropCursor(), EditorState.allowMultipleSelections.of(true),
        indentOnInput(), syntaxHighlighting(defaultHighlightStyle, { fallback: true }),
        bracketMatching(), closeBrackets(), rectangularSelection(), highlightActiveLine(),
        highlightSelectionMatches(), search({ top: true }), lintGutter(),
        indentUnit.of("    "), EditorState.tabSize.of(4), python(),
        keymap.of([
          ...keys, ...closeBracketsKeymap, ...defaultKeymap, ...searchKeymap,
          ...historyKeymap, ...foldKeymap,
        ]),
        EditorView.contentAttributes.of({
          "aria-label": host.dataset.label || "Controller code",
          "aria-multiline": "true",
        }),
        EditorView.updateListener.of((u) => {
          if (u.focusChanged) entry.focused = u.view.hasFocus;
          if (!u.docChanged) return;
          const text = u.state.doc.toString();
          if (text === entry.written) return; // the server's own text, just loaded
          entry.written = text;
          writeArea(entry.area, text);
          scheduleResend(entry);
        }),
      ],
    }),
  });
  entry.view = view;
  views.set(id, entry);
  if (selection) {
    const end = view.state.doc.length;
    const range = selection.main;
    view.dispatch({ selection: { anchor: Math.min(range.anchor, end), head: Math.min(range.head, end) } });
  }
  if (focused) { view.focus(); entry.focused = true; }
}

// The one span where two texts differ. Replacing only it keeps the cursor and the
// scroll where they are when the server's copy comes back late and differs from the
// editor's in a line or two (a whole-text replace put the cursor on line 1).
function smallestChange(doc, value) {
  const most = Math.min(doc.length, value.length);
  let head = 0;
  while (head < most && doc.charCodeAt(head) === value.charCodeAt(head)) head++;
  let tail = 0;
  while (
    tail < most - head &&
    doc.charCodeAt(doc.length - 1 - tail) === value.charCodeAt(value.length - 1 - tail)
  ) tail++;
  return { from: head, to: doc.length - tail, insert: value.slice(head, value.length - tail) };
}

function poll() {
  document.querySelectorAll("div.wart-editor[data-for]").forEach(mount);
  for (const [id, entry] of views) {
    if (!entry.view.dom.isConnected) { views.delete(id); forget(entry); continue; }
    let area = entry.area;
    if (!area.isConnected) { // React drew a new text area (a folder closed and opened)
      area = findArea(id);
      if (!area) continue;
      entry.area = area;
      hideArea(id, area);
    }
    const value = area.value;
    if (value !== entry.written) { // the server set the text: load it
      for (const t of entry.resend || []) clearTimeout(t); // never send older text over it
      entry.written = value;
      const doc = entry.view.state.doc.toString();
      if (doc !== value) entry.view.dispatch({ changes: smallestChange(doc, value) });
      // Echo it back: a resend of ours that crossed the server's text on the way put our
      // older text at the server, while this page shows the server's. Without the echo
      // the two stay apart, and Run would run what the student no longer sees.
      scheduleResend(entry);
    }
    const holder = document.querySelector(`div.wart-problems[data-for="${CSS.escape(id)}"]`);
    const json = holder ? holder.dataset.problems || "[]" : "[]";
    if (json !== entry.problems) {
      entry.problems = json;
      try { applyProblems(entry, JSON.parse(json)); } catch (e) { /* malformed: keep the old */ }
    }
  }
}

if (!window.wartEditor) {
  window.wartEditor = { mount, views, goToLine, editorFor, poll };
  document.addEventListener("click", holdEarlyPress, true);
  for (const type of ["pointerdown", "keydown", "input", "change", "click"]) {
    document.addEventListener(type, noteActivity, true);
  }
  // A line link acts on the press, not the click: a panel redrawn between press and
  // release (the server's next message) moved the link from under the pointer, and the
  // click landed on what took its place (seen on a busy page). Its default prevented,
  // the press leaves the focus -- and the cursor -- in the editor. Capture phase: the
  // panel's own handlers cannot stop it on the way down.
  const lineLink = (event) => event.target.closest && event.target.closest("[data-wart-line]");
  document.addEventListener("mousedown", (event) => {
    const link = lineLink(event);
    if (!link || event.button !== 0) return;
    event.preventDefault();
    goToLine(parseInt(link.dataset.wartLine, 10), link);
  }, true);
  document.addEventListener("click", (event) => {
    const link = lineLink(event);
    if (!link) return;
    event.preventDefault(); // never a jump to "#"
    // Enter on a focused link clicks without a press (detail 0): act on that one.
    if (event.detail === 0) goToLine(parseInt(link.dataset.wartLine, 10), link);
  }, true);
  setInterval(poll, 150);
  // A host drawn (or drawn anew) gets its editor at once, not at the next poll: keys typed
  // meanwhile would go nowhere.
  let queued = false;
  new MutationObserver(() => {
    if (queued) return;
    queued = true;
    queueMicrotask(() => { queued = false; poll(); });
  }).observe(document.body, { childList: true, subtree: true });
  poll();
}

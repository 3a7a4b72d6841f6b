"use strict";
// The control room's login: the operator's name and credential, checked by the office against the
// operators file; it answers with a session cookie the page's requests then carry.
document.getElementById("login").addEventListener("submit", async (e) => {
  e.preventDefault();
  const out = document.getElementById("login-result");
  out.textContent = ""; out.className = "";
  const body = { user: document.getElementById("user").value, secret: document.getElementById("secret").value };
  let res;
  try {
    res = await fetch("/api/login", { method: "POST", headers: { "Content-Type": "application/json" },
      body: JSON.stringify(body), credentials: "same-origin" });
  } catch (err) {
    out.textContent = "the office is unreachable"; out.className = "bad"; return;
  }
  if (res.ok) { window.location.assign("/"); return; }
  document.getElementById("secret").value = "";
  let message = `refused (${res.status})`;
  try { message = (await res.json()).message || message; } catch (err) { /* not JSON */ }
  out.textContent = message; out.className = "bad";
});

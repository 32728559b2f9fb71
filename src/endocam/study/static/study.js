// Interaction log of the study's video pages: play, pause, seek, rate change, end and the seconds
// of the video played at least once are posted to /api/event. With the manifest's must_watch rule
// the answer button stays disabled until the end of the video has been played, and logged, with
// at least data-min-watched-share of the video played on the way (the server checks the same
// rule): skipping ahead to the end does not count.
(function () {
  "use strict";
  const video = document.getElementById("study_video");
  if (!video) return;
  const videoId = video.dataset.videoId;
  const button = document.getElementById("answer_button");
  const mustWatch = video.dataset.mustWatch === "true";
  const minShare = Number(video.dataset.minWatchedShare || "0");
  const PROGRESS_EVERY_S = 5; // s of playing between "progress" reports
  const played = []; // disjoint, sorted [start, end] spans of media time played (s)
  let watched = 0; // s of media time played at least once: the spans' total length
  let last = video.currentTime; // media time at the previous timeupdate (the start until played:
  // a first timeupdate that comes before the play event still counts from 0)
  let reported = 0;

  function round(x) { return Math.round(x * 1000) / 1000; }

  function addPlayed(a, b) { // merge [a, b] into the played spans, update `watched`
    const merged = [];
    for (const [s, e] of played) {
      if (e < a || s > b) merged.push([s, e]);
      else { a = Math.min(a, s); b = Math.max(b, e); }
    }
    merged.push([a, b]);
    merged.sort(function (x, y) { return x[0] - y[0]; });
    played.length = 0;
    played.push.apply(played, merged);
    watched = played.reduce(function (sum, span) { return sum + span[1] - span[0]; }, 0);
  }

  function send(kind) {
    return fetch("/api/event", {
      method: "POST",
      headers: { "Content-Type": "application/json" },
      credentials: "same-origin",
      keepalive: true,
      body: JSON.stringify({
        video_id: videoId,
        kind: kind,
        media_time_s: round(video.currentTime || 0),
        playback_rate: video.playbackRate,
        watched_s: round(watched),
      }),
    }).catch(function () { return null; });
  }

  if (mustWatch && button) button.disabled = true;
  video.addEventListener("timeupdate", function () {
    const now = video.currentTime;
    if (!video.seeking && last !== null) {
      const step = now - last;
      if (step > 0 && step < 1.5 * Math.max(1, video.playbackRate)) addPlayed(last, now);
    }
    last = now;
    if (watched - reported >= PROGRESS_EVERY_S) { reported = watched; send("progress"); }
  });
  video.addEventListener("seeking", function () { last = null; });
  video.addEventListener("seeked", function () { last = video.currentTime; send("seeked"); });
  video.addEventListener("play", function () { if (last === null) last = video.currentTime; });
  ["play", "pause", "ratechange"].forEach(function (kind) {
    video.addEventListener(kind, function () { send(kind); });
  });
  video.addEventListener("ended", function () {
    if (last !== null && video.duration > last) addPlayed(last, video.duration);
    last = video.duration;
    const enough = watched >= minShare * video.duration;
    send("ended").then(function () { if (button && enough) button.disabled = false; });
  });
  const form = document.getElementById("answer_form");
  if (form) form.addEventListener("submit", function () { send("progress"); });
})();

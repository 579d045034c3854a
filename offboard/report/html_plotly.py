"""Plotly's JavaScript in a report page, compressed: ``report.html`` opens offline, so it carries plotly.js
(4.8 MB, three quarters of a 50 s flight's page). Here it is embedded gzip-compressed and base64-coded (1.9 MB),
unpacked in the page by the browser's own ``DecompressionStream`` (Chrome / Edge 80, Firefox 113, Safari 16.4
and later; an older browser shows one line saying so instead of the plots). The figures' scripts (plotly's
``to_html`` with ``include_plotlyjs=False``) and the page's glue are kept as text but marked deferred: they run,
in page order, once plotly.js is unpacked, as they would have run after an embedded plotly.js. The page then
sets ``document.body.dataset.slungReady = "1"``. No network request, no CDN.
"""

from __future__ import annotations

import base64
import functools
import gzip
import re

#: the type given to the page's scripts that need plotly (run by the loader, not by the browser's parser)
DEFERRED_TYPE = "text/x-slung-deferred"

_LOADER = """
(function () {
  function say(text) {
    const p = document.createElement('p');
    p.style.color = '#a00';
    p.textContent = text;
    document.body.insertBefore(p, document.body.firstChild);
  }
  function run(code) {
    const s = document.createElement('script');
    s.textContent = code;
    document.body.appendChild(s);
  }
  if (typeof DecompressionStream === 'undefined') {
    say('This browser cannot unpack the plots of this page (it needs DecompressionStream: Chrome or Edge 80, ' +
        'Firefox 113, Safari 16.4 or later). The metrics and events below are plain tables.');
    return;
  }
  const bin = atob(document.getElementById('slung-plotlyjs').textContent.trim());
  const bytes = new Uint8Array(bin.length);
  for (let i = 0; i < bin.length; i++) bytes[i] = bin.charCodeAt(i);
  const stream = new Blob([bytes]).stream().pipeThrough(new DecompressionStream('gzip'));
  new Response(stream).text().then(function (src) {
    run(src);
    document.querySelectorAll('script[type="DEFERRED"]').forEach(function (s) { run(s.textContent); });
    document.body.dataset.slungReady = '1';
  }, function (err) { say('The plots of this page could not be unpacked: ' + err); });
})();
""".replace("DEFERRED", DEFERRED_TYPE)


@functools.lru_cache(maxsize=1)
def _plotlyjs_gzip_base64() -> str:
    """plotly.js (the installed plotly's bundle), gzip-compressed and base64-coded; once per process (about 0.3 s
    of CPU)."""
    from plotly.offline import get_plotlyjs

    return base64.b64encode(gzip.compress(get_plotlyjs().encode("utf-8"), 6, mtime=0)).decode("ascii")


def defer(fragment: str) -> str:
    """``fragment`` (HTML) with each of its scripts marked to run once plotly.js is unpacked (:data:`DEFERRED_TYPE`)."""
    return re.sub(r"<script(?: type=\"text/javascript\")?>", f'<script type="{DEFERRED_TYPE}">', fragment)


def plotly_loader() -> str:
    """The compressed plotly.js and the script that unpacks it and then runs the deferred scripts; put it after
    them, at the end of the page's body."""
    return (
        f"<script type='application/octet-stream' id='slung-plotlyjs'>{_plotlyjs_gzip_base64()}</script>\n"
        f"<script>{_LOADER}</script>"
    )


__all__ = ["DEFERRED_TYPE", "defer", "plotly_loader"]

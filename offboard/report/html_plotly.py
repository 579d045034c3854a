"""Plotly's JavaScript and the figures' data in a report page, compressed: ``report.html`` opens offline, so it
carries plotly.js (4.8 MB, three quarters of a 50 s flight's page). Here it is embedded gzip-compressed and
base64-coded (1.9 MB), unpacked in the page by the browser's own ``DecompressionStream`` (Chrome / Edge 80,
Firefox 113, Safari 16.4 and later; an older browser shows one line saying so instead of the plots). The figures'
scripts (plotly's ``to_html`` with ``include_plotlyjs=False``: their data, decimated) are packed the same way
(:func:`pack`: 1.9 MB -> 1.2 MB for a 10-minute flight), the page's glue is kept as text but deferred
(:data:`DEFERRED_TYPE`); all run in page order once plotly.js is unpacked, as they would have run after an
embedded plotly.js. The page then sets ``document.body.dataset.slungReady = "1"``. No network request, no CDN.
:func:`unpacked` gives a page's text with its packed scripts unpacked (for tools and tests that read it).
"""

from __future__ import annotations

import base64
import functools
import gzip
import re

#: the type given to the page's scripts that need plotly (run by the loader, not by the browser's parser)
DEFERRED_TYPE = "text/x-slung-deferred"
#: the type of a deferred script packed with gzip and base64 (unpacked, then run, by the loader)
PACKED_TYPE = "application/x-slung-gzip"
_SCRIPT = re.compile(r"<script(?: type=\"text/javascript\")?>(.*?)</script>", re.S)
_PACKED = re.compile(f"<script type='{PACKED_TYPE}'>([A-Za-z0-9+/=]*)</script>")

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
  function unpack(b64) {
    const bin = atob(b64.trim());
    const bytes = new Uint8Array(bin.length);
    for (let i = 0; i < bin.length; i++) bytes[i] = bin.charCodeAt(i);
    return new Response(new Blob([bytes]).stream().pipeThrough(new DecompressionStream('gzip'))).text();
  }
  const later = document.querySelectorAll('script[type="DEFERRED"], script[type="PACKED"]');
  let chain = unpack(document.getElementById('slung-plotlyjs').textContent).then(run);
  later.forEach(function (s) {  // in page order: the figures, then the glue
    chain = chain.then(function () {
      return s.type === 'PACKED' ? unpack(s.textContent).then(run) : run(s.textContent);
    });
  });
  chain.then(function () { document.body.dataset.slungReady = '1'; },
             function (err) { say('The plots of this page could not be unpacked: ' + err); });
})();
""".replace("DEFERRED", DEFERRED_TYPE).replace("PACKED", PACKED_TYPE)


@functools.lru_cache(maxsize=1)
def _plotlyjs_gzip_base64() -> str:
    """plotly.js (the installed plotly's bundle), gzip-compressed and base64-coded; once per process (about 0.3 s
    of CPU)."""
    from plotly.offline import get_plotlyjs

    return _gzip_base64(get_plotlyjs())


def _gzip_base64(text: str) -> str:
    return base64.b64encode(gzip.compress(text.encode("utf-8"), 6, mtime=0)).decode("ascii")


def pack(fragment: str) -> str:
    """``fragment`` (HTML) with each of its scripts packed (gzip, base64; :data:`PACKED_TYPE`), to run once
    plotly.js is unpacked."""
    return _SCRIPT.sub(lambda m: f"<script type='{PACKED_TYPE}'>{_gzip_base64(m.group(1))}</script>", fragment)


def unpacked(page: str) -> str:
    """``page`` with every packed script's text unpacked in place (what the browser runs)."""
    return _PACKED.sub(
        lambda m: f"<script>{gzip.decompress(base64.b64decode(m.group(1))).decode('utf-8')}</script>", page
    )


def plotly_loader() -> str:
    """The compressed plotly.js and the script that unpacks it and then runs the deferred scripts; put it after
    them, at the end of the page's body."""
    return (
        f"<script type='application/octet-stream' id='slung-plotlyjs'>{_plotlyjs_gzip_base64()}</script>\n"
        f"<script>{_LOADER}</script>"
    )


__all__ = ["DEFERRED_TYPE", "PACKED_TYPE", "pack", "plotly_loader", "unpacked"]

"""``lunaralbedo view RESULTS_DIR``: serve the web map on localhost and open it in a browser."""
from __future__ import annotations

from pathlib import Path

import click

from ..errors import InputError
from ._common import reports_errors


@click.command("view")
@click.argument("results_dir", type=click.Path(file_okay=False, path_type=str))
@click.option("--port", type=int, default=8000, show_default=True, help="Port on localhost (0: any free port).")
@click.option("--host", default="127.0.0.1", show_default=True, help="Address to bind (the default is reachable from this machine only).")
@click.option("--no-browser", is_flag=True, help="Do not open a browser; just print the address.")
@click.option("--rebuild", is_flag=True, help="Run export-web first even when RESULTS_DIR/web exists.")
@reports_errors
def command(results_dir, port, host, no_browser, rebuild):
    """Serve RESULTS_DIR/web (made by export-web when missing) until Ctrl-C.

    RESULTS_DIR may also be a site folder itself (one holding index.html)."""
    from ..web.serve import make_server, url_of

    folder = Path(results_dir).expanduser().resolve()
    site = folder if (folder / "index.html").is_file() and not (folder / "report.json").exists() else folder / "web"
    if rebuild or not (site / "index.html").is_file():
        from ..web import export_web

        click.echo(f"building {site} (export-web) ...")
        export_web(folder)
    try:
        server = make_server(site, host, port)
    except OSError as exc:
        raise InputError(f"cannot serve on {host}:{port}: {exc.strerror or exc} (try --port 0)") from None
    url = url_of(server)
    click.echo(f"serving {site} at {url}  (Ctrl-C to stop)")
    if not no_browser:
        import webbrowser

        webbrowser.open(url)
    try:
        server.serve_forever()
    except KeyboardInterrupt:
        pass
    finally:
        server.server_close()

"""``relight serve``: a local web app around ``relight capture``.

``app`` builds the FastAPI application (page, JSON API, downloads), ``jobs`` holds the job
folders and the queue that runs each capture as a ``relight capture`` process,
``cmd_serve`` is the subcommand, ``static/`` the page (HTML, its script, a hand-written
WebGL2 viewer, the style), served by the app itself: nothing is fetched from the network.
Nothing here is imported by the rest of ``matcap`` except the subcommand's registration.
"""

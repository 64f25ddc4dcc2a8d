"""Every route that takes a request body reads it with the guarded JSON parser (limits on size
and depth, errors naming the field), found by walking the routers, not by a list kept by hand."""

from __future__ import annotations


def test_every_route_taking_a_body_parses_it_with_the_guarded_parser():
    import importlib
    import pkgutil

    from fastapi.routing import APIRoute
    from redline.server import routes
    from redline.server.core.bodies import JsonRoute

    taking = [
        route
        for info in pkgutil.iter_modules(routes.__path__)
        for route in importlib.import_module(f"{routes.__name__}.{info.name}").router.routes
        if isinstance(route, APIRoute) and route.methods & {"POST", "PUT", "PATCH"}
    ]
    assert len(taking) > 10
    assert [route.path for route in taking if not isinstance(route, JsonRoute)] == []

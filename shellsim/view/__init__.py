"""``shellsim view``: a shot in the browser (viser), a face beside :mod:`shellsim.cli`.

:mod:`shellsim.view.state` holds what is shown (bodies, their displayed meshes and embeddings, colours, the
motion and its frames, colliders, ground, cameras) as plain arrays, testable without a browser;
:mod:`shellsim.view.viewer` draws it with viser and runs the page's controls; :mod:`shellsim.view.worker`
runs the scene job in a worker process for "Simulate in place". viser is imported only when a viewer starts.
"""

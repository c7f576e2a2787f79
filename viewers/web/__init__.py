"""``wart viewer``: the browser WARTApp on viser (thesis chapter 7, future work 9.2).

Modules, one concern each:

    address.py     the address bar's parser (pure) and saved connections (JSON)
    adapters.py    the Protocols the viewer talks through (lab connection, world feed)
    demo_lab.py    the demo lab: in-memory implementations of those Protocols (--demo, tests, bench)
    geometry.py    mm/radian world poses to viser metres/quaternions (pure numpy)
    world_view.py  one browser's top-down arena view: batched robots, trail, rays
    pump.py        the paced loop that pushes the newest frame to every watching view
    login.py       the per-browser login modal
    masked.py      password inputs shown as dots (a style rule beside viser's text input)
    lobby.py       a lab's lobby tab (directory, join, host)
    chat_panel.py  a context's tab (history, members, live lines, kick, leave)
    robot_panel.py agents, queue, controller upload, live sensor plots
    editor.py      map editor: transform controls, add/delete through WorldFeed.edit
    client.py      per-browser state: address bar, tabs, open labs
    app.py         the viser server, the Zenoh session and token, ``main()``
"""

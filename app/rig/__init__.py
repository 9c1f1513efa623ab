"""The rig as the app composes it, one module per job: building it (:mod:`app.rig.build`), turning
actions into touches (:mod:`app.rig.actions`) and the collection loop (:mod:`app.rig.collection`).

``hardware`` knows devices and ``core`` knows DMPs; neither imports the other: they meet here.
"""

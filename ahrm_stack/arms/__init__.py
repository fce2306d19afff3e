"""Arms built from URDF files: locating the files (:mod:`.assets`), reading them (:mod:`.urdf`),
their meshes (:mod:`.meshes`) and the MuJoCo composer entity (:mod:`.entity`)."""

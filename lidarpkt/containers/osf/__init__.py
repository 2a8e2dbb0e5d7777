"""OSF, ouster-sdk's recording format: a container of decoded frames and their sensors' descriptions.

:mod:`.format` declares the file's flatbuffers tables, identifiers and field types once; :mod:`.codecs`
decodes the PNG and ZPNG images fields are stored in; :mod:`.reader` reads a file's index and the
stored fields of its frame messages. What the fields mean, and the frames built from them, is the
sensor vendor's (``lidarpkt.vendors``, through the registry).
"""

//! glTF import (in progress).
